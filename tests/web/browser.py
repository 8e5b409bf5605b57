"""The headless Chromium both browser suites drive (Selenium): the same
flags for both, so that a page behaves alike in each."""

from __future__ import annotations

import os

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("CHROMEDRIVER", "/usr/bin/chromedriver")


def headless_chromium(profile: str, prefs: dict | None = None) -> webdriver.Chrome:
    """A browser with its profile in `profile` (a fresh directory), no
    network of its own beyond the page, a window large enough for every
    panel; `prefs` are Chromium preferences (downloads, say)."""
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync",
                 f"--user-data-dir={profile}", "--window-size=1600,1000"]:
        opts.add_argument(flag)
    if prefs:
        opts.add_experimental_option("prefs", prefs)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
