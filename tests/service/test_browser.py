"""The web page in a real headless browser (Debian's chromium and chromedriver, through
selenium): log in with a token, open the servo model, run it, see its plot image loaded.
With SPIDERSIM_SCREENSHOT=path the page is also saved as a PNG (docs/service_page.png)."""
from __future__ import annotations

import os
import shutil
import tempfile

import pytest

from .conftest import Server, add_user

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
