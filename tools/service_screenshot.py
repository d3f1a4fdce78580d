"""Screenshot of the service's web page for the README (docs/service_page.png).

    spidersim serve --add-user me          # prints TOKEN
    spidersim serve &
    python tools/service_screenshot.py http://127.0.0.1:8050 TOKEN [--model spider]

Logs in with headless chromium (selenium), runs the model with its defaults, waits for the
plots and the 3-D arm view, and saves the page.
"""
import argparse
import os
import shutil
import tempfile

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

ap = argparse.ArgumentParser()
ap.add_argument("url")
ap.add_argument("token")
ap.add_argument("--model", default="spider")
ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "docs",
                                              "service_page.png"))
a = ap.parse_args()
profile = tempfile.mkdtemp()
opts = webdriver.ChromeOptions()
opts.binary_location = shutil.which("chromium")
for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--no-first-run", f"--user-data-dir={profile}", "--window-size=1280,1900"):
    opts.add_argument(arg)
drv = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
try:
    wait = WebDriverWait(drv, 600)
    drv.get(a.url + "/")
    drv.find_element(By.ID, "token").send_keys(a.token)
    drv.find_element(By.ID, "login").click()
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f"#models li[data-name={a.model}]"))
    drv.find_element(By.CSS_SELECTOR, f"#models li[data-name={a.model}]").click()
    wait.until(lambda d: a.model in d.find_element(By.ID, "m-title").text)
    drv.find_element(By.ID, "run").click()
    wait.until(lambda d: d.find_element(By.ID, "state").text.startswith(("done", "failed")))
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#plots img.plot") and all(
        d.execute_script("return arguments[0].complete && arguments[0].naturalWidth", i)
        for i in d.find_elements(By.CSS_SELECTOR, "#plots img.plot")))
    if drv.find_elements(By.CSS_SELECTOR, "#arm-box:not([hidden])"):
        drv.execute_script("const r = document.getElementById('arm-time');"
                           "r.value = Math.floor(r.max * 0.7); r.oninput();")
    drv.save_screenshot(a.out)
    print("wrote", a.out)
finally:
    drv.quit()
    shutil.rmtree(profile, ignore_errors=True)
