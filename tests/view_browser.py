"""The live view's page in a headless Chromium or Firefox (driven by selenium), run by
tests/all/view.rs: load the page, see a frame, drag with the left button, see the camera change
(GET /camera) and a frame of the new camera. Usage: view_browser.py URL chromium|firefox DRIVER
BROWSER [SCREENSHOT.png [WIDTHxHEIGHT]], DRIVER being chromedriver or geckodriver and BROWSER the
browser's executable: with a path, once the frame of the new camera is refined to its samples, a
screenshot of the window (scripts/view-screenshot.sh makes the README's). Exit 0 when all of that
happened; otherwise 1, saying what did not."""

import json
import sys
import time
import urllib.request
from urllib.parse import urlsplit, urlunsplit

from selenium import webdriver
from selenium.webdriver.chrome.service import Service as ChromeService
from selenium.webdriver.firefox.service import Service as FirefoxService
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By

LIMIT = 60.0  # seconds any one wait may take


def api(url, path):
    """GET path of the view at url (keeping its token)."""
    parts = urlsplit(url)
    with urllib.request.urlopen(urlunsplit((parts.scheme, parts.netloc, path, parts.query, "")), timeout=LIMIT) as r:
        return json.loads(r.read())


def wait_for(what, test, limit=LIMIT):
    start = time.monotonic()
    while time.monotonic() - start < limit:
        v = test()
        if v:
            return v
        time.sleep(0.1)
    print(f"view_browser: {what} did not happen within {limit:.0f} s", file=sys.stderr)
    sys.exit(1)


def main():
    url, kind, driver_path, browser = sys.argv[1:5]
    screenshot = sys.argv[5] if len(sys.argv) > 5 else None
    width, height = (sys.argv[6] if len(sys.argv) > 6 else "640x480").split("x")
    if kind == "chromium":
        options = webdriver.ChromeOptions()
        options.binary_location = browser
        for a in ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", f"--window-size={width},{height}"]:
            options.add_argument(a)
        driver = webdriver.Chrome(service=ChromeService(executable_path=driver_path), options=options)
    elif kind == "firefox":
        options = webdriver.FirefoxOptions()
        options.binary_location = browser
        for a in ["-headless", f"--width={width}", f"--height={height}"]:
            options.add_argument(a)
        driver = webdriver.Firefox(service=FirefoxService(executable_path=driver_path), options=options)
    else:
        print(f"view_browser: unknown browser kind {kind!r} (chromium or firefox)", file=sys.stderr)
        sys.exit(2)
    try:
        driver.set_page_load_timeout(LIMIT)
        driver.get(url)
        img = driver.find_element(By.ID, "frame")
        frames = lambda: int(img.get_attribute("data-frames") or 0)
        wait_for("a first frame", lambda: frames() >= 1 and driver.execute_script("return arguments[0].naturalWidth", img) > 0)
        before = api(url, "/camera")
        shown = frames()
        ActionChains(driver).move_to_element(img).click_and_hold().move_by_offset(12, 0).move_by_offset(12, 4).move_by_offset(12, 4).release().perform()
        after = wait_for("a camera change", lambda: (c := api(url, "/camera")) != before and c)
        turned = any(abs(a - b) > 1e-6 for a, b in zip(after["position"], before["position"]))
        if not turned or after["focal_point"] != before["focal_point"]:
            print(f"view_browser: a left drag should turn the position about the focal point: {before} -> {after}", file=sys.stderr)
            sys.exit(1)
        seq = api(url, "/stats")["seq"]
        wait_for(f"a frame of camera seq {seq}", lambda: frames() > shown and int(img.get_attribute("data-seq") or -1) >= seq)
        if screenshot:
            wait_for("the refined frame", lambda: (s := api(url, "/stats"))["seq"] >= seq and s["spp_reached"] == s["spp"], limit=300)
            time.sleep(1.0)
            driver.save_screenshot(screenshot)
        print(f"view_browser: ok: {kind}, {frames()} frames, camera {before['position']} -> {after['position']}, seq {seq}")
    finally:
        driver.quit()


if __name__ == "__main__":
    main()
