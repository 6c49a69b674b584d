"""The diagnosis report rendered in a real browser (headless Chromium from the
distribution's packages; .ci/run installs it): every plot loads, the console
shows no error, nothing is fetched from the network, the verdict, decisions,
truth and provenance are on the page; a screenshot is saved."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from cmmpose.cli import main

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

if not (CHROMIUM and DRIVER):
    if os.environ.get("CI"):
        pytest.fail("CI must install chromium and chromium-driver (Debian packages) for the browser test",
                    pytrace=False)
    pytest.skip("needs chromium and chromedriver (apt-get install chromium chromium-driver)", allow_module_level=True)

webdriver = pytest.importorskip("selenium.webdriver")


@pytest.mark.slow
def test_report_renders_in_chromium(tmp_path):
    run_dir, report, model = tmp_path / "run", tmp_path / "report" / "diagnose.html", tmp_path / "model.json"
    res = CliRunner().invoke(main, ["simulate", "--effect", "squareness:yz=20", "--effect",
                                    "scanner-scale:lateral=0.0006", "--seed", "2", "-o", str(run_dir)],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["diagnose", str(run_dir), "--report", str(report.parent), "--save-model", str(model),
                                    "--max-effects", "3"], catch_exceptions=False)
    assert res.exit_code == 0, res.output

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1200,3000",
                "--disable-dev-shm-usage"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=webdriver.ChromeService(executable_path=DRIVER), options=options)
    try:
        driver.get(report.resolve().as_uri())
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight, i.alt]);")
        assert len(images) >= 5, images
        assert all(done and w > 100 and h > 100 for done, w, h, _ in images), images
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
        assert errors == [], errors
        fetched = driver.execute_script(
            "return performance.getEntriesByType('resource').map(e => e.name).filter(n => !n.startsWith('data:'));")
        assert fetched == [], fetched  # offline: everything is embedded
        text = driver.find_element("tag name", "body").text
        for heading in ("Verdict", "Decision on every candidate effect", "Found against the simulator's truth",
                        "The error falling", "Provenance"):
            assert heading in text, heading
        assert "The model was missing" in text and "squareness" in text and "arcsec" in text
        assert str(model) in text and str(run_dir) in text  # provenance names the model and the run
        headers = [th.text for th in driver.find_elements("tag name", "th")]
        assert headers and not [h for h in headers if "_" in h], headers  # readable headers, not code names
        assert "rms_accuracy_error_um" not in text and "=+1 1" not in text  # no dimensionless unit "1"
        shot = Path(os.environ.get("CMMPOSE_SCREENSHOT_DIR", tmp_path)) / "diagnosis-report.png"
        shot.parent.mkdir(parents=True, exist_ok=True)
        assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 50_000
    finally:
        driver.quit()
