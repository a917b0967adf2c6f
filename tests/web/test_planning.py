"""Planning in the browser: validation errors inline at the field they name, a plan made
and previewed (predicted trajectories and 3D motion) before anything is uplinked, and a
pass scheduled from it."""

from __future__ import annotations

import pytest

from tests.server.link.harness import Ground
from tests.support.web import OPERATOR_TOKEN, VIEWER_TOKEN, Console

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def test_operator_validates_plans_previews_and_schedules(console: Console, ground: Ground) -> None:
    page = console.page
    console.sign_in(OPERATOR_TOKEN, "#/plan")
    page.select_option("[data-test=experiment]", "ptp")
    page.fill("[data-field=settle_s] input", "99999")
    page.fill("[data-field=goal_joints_deg] input", "5, 0, 0, 0, 0, 0")
    page.click("[data-test=validate]")
    error = page.locator("[data-test=error-settle_s]")
    error.wait_for()
    page.wait_for_function(
        "() => document.querySelector('[data-test=error-settle_s]').textContent.length > 0"
    )
    assert "settle_s" in error.text_content()
    assert "3600" in error.text_content()  # the limit, as the planner states it
    assert page.locator("[data-field=settle_s] input.invalid").count() == 1
    assert page.locator("[data-test=validation-errors]").is_visible()
    console.screenshot("plan-validation-error")

    page.fill("[data-field=settle_s] input", "10")
    page.click("[data-test=validate]")
    page.wait_for_selector("[data-test=validation-ok]")
    assert page.text_content("[data-test=error-settle_s]") == ""

    page.click("[data-test=create-plan]")
    page.wait_for_selector("[data-test=plan-info] h3")
    assert page.text_content("[data-test=plan-info] h3").startswith("ptp")
    # The prediction is on the plots, and the motion plays in 3D before any uplink.
    page.wait_for_function(
        "() => Number(document.querySelector('[data-test=joint-plots] .plot').dataset.points) > 10"
    )
    page.click("[data-test=preview-play]")
    page.wait_for_timeout(600)
    page.click("[data-test=preview-play]")
    assert float(page.input_value("[data-test=preview-scrub]")) > 0
    console.screenshot("plan-preview")

    page.fill("[data-test=pass-name-input]", "web-planned")
    page.click("[data-test=schedule-submit]")
    page.wait_for_selector("[data-test=open-live]")
    page.click("[data-test=open-live]")
    page.wait_for_function(
        "() => document.querySelector('[data-test=pass-name]')?.textContent === 'web-planned'"
    )
    assert page.text_content("[data-test=pass-state]") == "SCHEDULED"


def test_viewer_cannot_plan(console: Console) -> None:
    page = console.page
    console.sign_in(VIEWER_TOKEN, "#/plan")
    page.wait_for_selector("[data-test=viewer-note]")
    assert page.locator("[data-test=validate], [data-test=create-plan]").count() == 0
    console.screenshot("plan-viewer")
