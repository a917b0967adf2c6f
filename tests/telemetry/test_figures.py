"""Figures of the demo pass's analyses: PNG bytes, deterministic, no pyplot state left."""

from __future__ import annotations

import io

import matplotlib
import pytest

from telemetry.analysis import PassAnalysis, analyse_pass
from telemetry.recording import PassRecording

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def analysis(demo_recording: PassRecording) -> PassAnalysis:
    return analyse_pass(demo_recording)


def test_every_figure_is_a_png_and_nothing_stays_open(analysis: PassAnalysis) -> None:
    from matplotlib import image, pyplot

    from telemetry.figures import pass_figures, phase_plane_figure

    before = pyplot.get_fignums()
    figures = pass_figures(analysis)
    assert set(figures) == {
        "reaction",
        "joint_tracking",
        "hand_attitude",
        "phase_plane",
        "endpoint",
        "predicted_vs_flown",
    }
    for name, png in figures.items():
        assert png.startswith(PNG_MAGIC), name
        pixels = image.imread(io.BytesIO(png))
        assert pixels.shape[0] >= 300 and pixels.shape[1] >= 600, (name, pixels.shape)
        # Something was drawn: not a blank canvas.
        assert float(pixels[..., :3].std()) > 0.01, name
    assert pyplot.get_fignums() == before
    assert matplotlib.get_backend().lower() == "agg"
    assert analysis.phase_plane is not None
    assert phase_plane_figure(analysis.phase_plane) == figures["phase_plane"]
