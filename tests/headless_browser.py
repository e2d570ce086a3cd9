"""A real headless browser on the daemon's web page: Debian's chromium driven through chromedriver by selenium.

``headless_chromium`` opens one (the ``browser`` fixture of tests/conftest.py), or skips the test
where the machine has none (fails under CI, which installs them); ``port_of`` is the web page's
port of a :class:`tests.gated_daemon.GatedDaemon`; ``wait_until`` waits for what the page shows.
"""

import contextlib
import os
import shutil
import tempfile
import time

import pytest


def chromium():
    """(chromium, chromedriver) of this machine, or the reason there are none."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if browser and driver:
        return browser, driver
    if os.environ.get("CI") or os.environ.get("CRYOD_REQUIRE_BROWSER"):
        pytest.fail("the browser test needs Debian's chromium and chromium-driver (.ci/run installs them)")
    pytest.skip("no chromium and chromedriver on this machine: apt-get install chromium chromium-driver")


@contextlib.contextmanager
def headless_chromium(folder):
    """A selenium session of a headless chromium whose profile is in ``folder``, quit at the end."""
    selenium = pytest.importorskip("selenium.webdriver")
    binary, driver = chromium()
    options = selenium.ChromeOptions()
    options.binary_location = binary
    for argument in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1300,1500",
                     f"--user-data-dir={tempfile.mkdtemp(dir=folder)}"):
        options.add_argument(argument)
    from selenium.webdriver.chrome.service import Service

    session = selenium.Chrome(options=options, service=Service(driver))
    try:
        yield session
    finally:
        session.quit()


def port_of(daemon) -> int:
    """The port of a gated daemon's web page (served by its interfaces process)."""
    return daemon.port("web")


def wait_until(condition, what: str, timeout_s: float = 20.0):
    """Wait until ``condition()`` holds; fail saying the page did not ``what`` within the timeout."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"the page did not {what} within {timeout_s:g} s"
        time.sleep(0.05)
