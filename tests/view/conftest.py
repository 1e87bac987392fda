"""Participant-view test fixtures: headless Chromium (Debian's, driven by its chromedriver) and helpers.

The browser is never skipped: when Chromium or its driver is missing the fixture errors and says how to
install them (``bash scripts/ensure-browser.sh``). Screenshots go to ``$STUDYCTL_SCREENSHOTS`` when set,
else to ``screenshots/`` in pytest's temporary folder (the path is printed in the test report).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = os.environ.get("STUDYCTL_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("STUDYCTL_CHROMEDRIVER", "/usr/bin/chromedriver")
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--window-size=1280,800",
)


def _new_browser(profile: Path):
    for exe in (CHROMIUM, CHROMEDRIVER):
        if not (Path(exe).is_file() or shutil.which(exe)):
            pytest.fail(f"{exe} is missing: the participant-view tests need Debian's Chromium and its driver; "
                        "install them with `bash scripts/ensure-browser.sh`", pytrace=False)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in FLAGS:
        opts.add_argument(flag)
    opts.add_argument(f"--user-data-dir={profile}")
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(20)
    return driver


@pytest.fixture(scope="session")
def new_browser(tmp_path_factory):
    """A factory of fresh headless Chromium sessions (each with its own profile); all quit at the end."""
    made = []

    def make():
        driver = _new_browser(tmp_path_factory.mktemp("chromium-profile"))
        made.append(driver)
        return driver

    yield make
    for d in made:
        process = getattr(getattr(d, "service", None), "process", None)
        if process is not None and process.poll() is not None:
            continue  # a test quit it already
        try:
            d.quit()
        except Exception:  # the browser died on its own: nothing left to stop
            pass


@pytest.fixture(scope="session")
def browser(new_browser):
    """One shared headless Chromium for the tests of this folder."""
    return new_browser()


@pytest.fixture(scope="session")
def shots(tmp_path_factory):
    env = os.environ.get("STUDYCTL_SCREENSHOTS")
    folder = Path(env) if env else tmp_path_factory.getbasetemp() / "screenshots"
    folder.mkdir(parents=True, exist_ok=True)

    def save(driver, name: str) -> Path:
        path = folder / f"{name}.png"
        driver.save_screenshot(str(path))
        return path

    save.folder = folder
    return save


@pytest.fixture
def store(tmp_path):
    """A fresh SQLite study store of the view tests' own (the root ``store`` runs on both backends)."""
    from studyctl.store import StudyStore

    s = StudyStore.create(tmp_path / "study.db")
    yield s
    s.close()
