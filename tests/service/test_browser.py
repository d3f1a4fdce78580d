"""The web page in a real headless browser (Debian's chromium and chromedriver, through
selenium): log in with a token, open the servo model, run it, see its plot image loaded;
the disk-quota line and the Delete buttons of finished jobs.
With SPIDERSIM_SCREENSHOT=path the page is also saved as a PNG (docs/service_page.png)."""
from __future__ import annotations

import os
import re
import shutil
import tempfile
import time

import pytest

from spidersim.service.store import Store

from .conftest import Server, add_user, cli, wait_state

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

pytestmark = pytest.mark.skipif(
    not (CHROMIUM and DRIVER),
    reason="chromium and chromedriver are not installed (apt-get install chromium "
           "chromium-driver; CI installs them)")


@pytest.fixture
def browser():
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service
    profile = tempfile.mkdtemp(prefix="spidersim-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--disable-background-networking", "--disable-component-update",
              "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
              "--window-size=1280,1500"):
        opts.add_argument(a)
    drv = webdriver.Chrome(service=Service(DRIVER), options=opts)
    yield drv
    drv.quit()
    shutil.rmtree(profile, ignore_errors=True)


def test_log_in_run_servo_see_plot(tmp_path, models_dir, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as EC
    from selenium.webdriver.support.ui import WebDriverWait
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1"])
    tok = add_user(data, "erin")
    srv.start()
    try:
        wait = WebDriverWait(browser, 90)
        browser.get(srv.url + "/")
        browser.find_element(By.ID, "token").send_keys("sst_wrong_token")
        browser.find_element(By.ID, "login").click()
        wait.until(lambda d: "rejected" in d.find_element(By.ID, "login-error").text)
        box = browser.find_element(By.ID, "token")
        box.clear()
        box.send_keys(tok)
        browser.find_element(By.ID, "login").click()
        wait.until(EC.element_to_be_clickable((By.CSS_SELECTOR, "#models li[data-name=servo]")))
        browser.find_element(By.CSS_SELECTOR, "#models li[data-name=servo]").click()
        wait.until(lambda d: "servo" in d.find_element(By.ID, "m-title").text)
        assert "DC motor position servo" in browser.find_element(By.ID, "m-desc").text
        t_end = browser.find_element(By.ID, "t_end")
        t_end.clear()
        t_end.send_keys("0.4")
        browser.find_element(By.ID, "run").click()
        wait.until(lambda d: d.find_element(By.ID, "state").text.startswith(("done", "failed")))
        assert browser.find_element(By.ID, "state").text.startswith("done"), \
            browser.find_element(By.ID, "message").text
        # the plots are fetched with the token and shown: loaded images with a real size
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#plots img.plot")) == 3)
        wait.until(lambda d: all(d.execute_script(
            "return arguments[0].complete && arguments[0].naturalWidth", img) > 100
            for img in d.find_elements(By.CSS_SELECTOR, "#plots img.plot")))
        titles = [i.get_attribute("alt") for i in
                  browser.find_elements(By.CSS_SELECTOR, "#plots img.plot")]
        assert "position.png" in titles
        shot = os.environ.get("SPIDERSIM_SCREENSHOT")
        if shot:
            browser.save_screenshot(shot)
    finally:
        srv.stop()


def usage_kb(text):
    """The 'used N kB' figure of the page's usage line, in bytes."""
    m = re.search(r"used ([\d.]+) kB of 1 MB", text)
    assert m, text
    return float(m.group(1)) * 1e3


def test_quota_usage_and_delete_buttons(tmp_path, models_dir, browser):
    """The disk use is shown and refreshed when a job finishes and when one is deleted,
    with a note once the quota cannot take another run; a finished job's Delete button
    asks first (dismissed: nothing deleted), then deletes (the files go, the job stays
    listed without its button); a refusal of the server is shown as its text."""
    from selenium.common.exceptions import (ElementNotInteractableException,
                                            StaleElementReferenceException)
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as EC
    from selenium.webdriver.support.ui import WebDriverWait
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1", "--max-user-mb", "1",
                                    "--max-record-mb", "0.9"])
    tok = add_user(data, "erin")
    srv.start()
    http = srv.client(tok)
    try:
        first = http.post("/jobs", json={"model": "servo", "t_end": 0.05,
                                         "plots": False}).json()["id"]
        assert wait_state(http, first)["state"] == "done"
        # the job list is redrawn on its refreshes: an element found may go stale
        wait = WebDriverWait(browser, 90, ignored_exceptions=[
            StaleElementReferenceException, ElementNotInteractableException])

        def click(css):
            """Click the element of ``css`` once it is clickable, found again if redrawn."""
            wait.until(lambda d: d.find_element(By.CSS_SELECTOR, css).click() or True)

        browser.get(srv.url + "/")
        browser.find_element(By.ID, "token").send_keys(tok)
        browser.find_element(By.ID, "login").click()
        usage = lambda: browser.find_element(By.ID, "usage").text    # noqa: E731
        wait.until(lambda d: "used" in usage())
        assert usage_kb(usage()) == pytest.approx(http.get("/usage").json()["used_bytes"],
                                                  rel=0.01, abs=1e3)
        assert not browser.find_element(By.ID, "usage-full").is_displayed()
        # a run from the page: its job is listed as it finishes, the usage refreshed
        wait.until(EC.element_to_be_clickable((By.CSS_SELECTOR, "#models li[data-name=servo]")))
        browser.find_element(By.CSS_SELECTOR, "#models li[data-name=servo]").click()
        wait.until(lambda d: "servo" in d.find_element(By.ID, "m-title").text)
        t_end = browser.find_element(By.ID, "t_end")
        t_end.clear()
        t_end.send_keys("0.4")
        browser.find_element(By.ID, "run").click()
        wait.until(lambda d: d.find_element(By.ID, "state").text.startswith(("done", "failed")))
        assert browser.find_element(By.ID, "state").text.startswith("done")
        jobs = http.get("/jobs").json()
        second = next(j["id"] for j in jobs if j["id"] != first)
        used = http.get("/usage").json()
        assert used["active_jobs"] == 0 and used["free_bytes"] < 0.9e6  # no room for a run
        wait.until(lambda d: usage_kb(usage()) == pytest.approx(used["used_bytes"], rel=0.01))
        wait.until(lambda d: d.find_element(By.ID, "usage-full").is_displayed())
        full = browser.find_element(By.ID, "usage-full").text
        assert full.startswith("Quota full: a new run needs 900 kB free"), full
        # Delete asks first: dismissed, nothing happens
        button = f"#jobs li[data-id='{second}'] button.del"
        click(button)
        wait.until(EC.alert_is_present())
        assert "Delete the results of job servo done" in browser.switch_to.alert.text
        browser.switch_to.alert.dismiss()
        assert not http.get(f"/jobs/{second}").json()["expired"]
        # accepted: deleted, its button gone, the usage down and the note gone
        click(button)
        wait.until(EC.alert_is_present())
        browser.switch_to.alert.accept()
        wait.until(lambda d: "files removed" in d.find_element(
            By.CSS_SELECTOR, f"#jobs li[data-id='{second}']").text)
        assert http.get(f"/jobs/{second}").json()["expired"]
        assert not browser.find_elements(By.CSS_SELECTOR, button)
        assert not browser.find_element(By.ID, "results").is_displayed()   # it was shown
        left = http.get("/usage").json()["used_bytes"]
        wait.until(lambda d: usage_kb(usage()) == pytest.approx(left, rel=0.01, abs=1e3))
        assert not browser.find_element(By.ID, "usage-full").is_displayed()
        assert browser.find_element(By.ID, "jobs-error").text == ""
        # a refusal (the user's token revoked meanwhile) is shown as the server's text
        cli("serve", "--revoke-user", "erin", "--data", str(data))
        click(f"#jobs li[data-id='{first}'] button.del")
        wait.until(EC.alert_is_present())
        browser.switch_to.alert.accept()
        wait.until(lambda d: "Could not delete job servo done" in d.find_element(
            By.ID, "jobs-error").text)
        time.sleep(1)                   # the list's refresh after the refusal has answered
        shown = browser.find_element(By.ID, "jobs-error").text
        assert shown.count("a valid token is required") == 1, shown     # once, readable
        assert browser.find_elements(By.CSS_SELECTOR, f"#jobs li[data-id='{first}'] button.del")
        assert not Store(str(data)).get_job(first)["expired"]          # nothing deleted
    finally:
        http.close()
        srv.stop()
