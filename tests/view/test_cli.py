"""`studyctl run --view` end to end: a person session in a real terminal (pseudo-terminal) with the
participant view open in headless Chromium; the participant answers in the browser, the coordinator
keeps the terminal (ends practice early); then the database is checked."""

from __future__ import annotations

import sys

import pytest
from selenium.webdriver.common.by import By
from test_browser import click, wait_screen
from view_support import PtyProcess, wait_for

from studyctl.store.workspace import open_study

pytestmark = pytest.mark.slow

@pytest.fixture
def workspace(pty_workspace):
    """The engine's small terminal-test study: palpation (no visual channel), grid reports, 2 conditions."""
    return pty_workspace


@pytest.mark.slow
def test_run_with_view_prints_url_and_takes_answers_from_the_browser(workspace, browser, shots):
    ws, env = workspace
    proc = PtyProcess([sys.executable, "-m", "studyctl", "run", "--participant", "PTY-AAAAA", "--view"], ws, env)
    url = proc.expect(r"Participant view: (http://127\.0\.0\.1:\d+/v/[\w-]+/)").group(1)
    browser.get(url)
    wait_screen(browser, "instructions", 20)
    assert "Find the tumours" in browser.find_element(By.ID, "ins-text").text
    click(browser, "#btn-ready")
    proc.expect(r"\(answered in the participant view\)")
    for trial, codes in ((1, (4,)), (2, (5, 3))):
        if trial == 2:
            wait_screen(browser, "timer", 20)  # the break between the trials counts down
            shots(browser, "11_cli_break_countdown")
        # practice with the condition's feedback: started and ended by the participant in the view
        wait_screen(browser, "trial_ready", 20)
        assert browser.find_element(By.ID, "btn-start").text == "Start the practice"
        click(browser, "#btn-start")
        wait_screen(browser, "trial")
        assert browser.find_element(By.ID, "heading").text.startswith("Practice")
        click(browser, "#btn-finish")
        wait_for(lambda: browser.find_element(By.ID, "btn-start").text == "Start the trial", 20, "the trial")
        wait_screen(browser, "trial_ready", 20)
        click(browser, "#btn-start")
        wait_screen(browser, "trial")
        wait_for(lambda: browser.find_element(By.ID, "no-visual").is_displayed(), 5, "no visual channel")
        if trial == 1:
            cells = browser.find_elements(By.CSS_SELECTOR, "#report-grid button")
            assert len(cells) == 49
            next(b for b in cells if b.text == "3 4").click()
            wait_for(lambda: browser.find_element(By.ID, "notice").text == "Reported 3 4", 5, "report")
            shots(browser, "12_cli_grid_report_no_visual")
        click(browser, "#btn-finish")
        for code in codes:
            wait_screen(browser, "item", 20)
            prompt = browser.execute_script("return window.studyctlView.state().screen.prompt.id")
            browser.find_element(By.CSS_SELECTOR, f"#scale button[data-code='{code}']").click()
            wait_for(lambda p=prompt: browser.execute_script(
                "const s = window.studyctlView.state().screen; return !s.prompt || s.prompt.id !== arguments[0]", p),
                10, "the next screen")
    wait_screen(browser, "done", 20)
    assert proc.wait(30) == 0
    proc.expect(r"Session 1 \(PTY-AAAAA\): completed; 2 trials completed, 0 aborted, 0 invalid, 3 answers")
    with open_study(workspace=ws) as o:
        resp = o.store.responses_frame()
        assert list(zip(resp.item, resp.code, strict=True)) == [("easy", 4), ("easy", 5), ("prefer_feedback", 3)]
        trials = o.store.list_trials()
        reports = [r.payload for t in trials for r in o.store.location_reports(t.id)]
        assert reports == [{"column": "3", "row": "4"}]
        events = o.store.events_frame(1)
        assert (events.kind == "view_answer").sum() >= 7  # ready, 2 × start, 3 items (+ practice prompts)
        assert any(p["action"] == "connected" for p in events[events.kind == "view_client"].payload)
