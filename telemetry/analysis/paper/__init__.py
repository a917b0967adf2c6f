"""The paper's flight results and a pass's analyses held against them ("flight against ours").

:data:`PAPER_RESULTS` is the one place where the flight's numbers and our criteria live, each
with the paper section it comes from (Yoshida et al., "Flight experiments of ETS-VII for
advanced space robot control", 2002; SPEC sections 3 and 4). :func:`compare_with_flight`
measures each result on a pass's **stored documents** (the JSON numbers of
:func:`telemetry.analysis.analyse_pass`, the inertia identification and the
gravity-gradient re-simulation, as :mod:`server.services.analyses` stores them), so the
report computes the table for every pass and a recalibration changes only what "ours"
measures, never the flight's numbers or the criteria.

A verdict is computed, never written down: ``reproduced`` when the criterion holds on this
pass's numbers, ``not reproduced`` when it does not, ``not measured`` when the analysis it
needs is absent, failed, or lacks the number (never counted as a pass).

The orderings of experiments 1 and 3 (which leg, which variant is larger or faster) are also
here (:func:`reaction_ordering`, :func:`phase_plane_ordering`), for the report's tables and
the figures.

The package, each module one part (everything public is named here):

    documents    the stored documents (Sources) and how their numbers are read
    results      PAPER_RESULTS, each result with its check
    comparison   the table against the flight, or against the pass's own plan
    orderings    experiments 1 and 3's orderings against the flight's
"""

from telemetry.analysis.paper.comparison import (
    MIN_SETTLE_TOLERANCE_S,
    NOT_MEASURED,
    NOT_REPRODUCED,
    REPRODUCED,
    Comparison,
    Predicted,
    compare_with_flight,
    compare_with_plan,
    verdict,
)
from telemetry.analysis.paper.documents import Sources, ordered
from telemetry.analysis.paper.orderings import (
    FLIGHT_FASTEST_SETTLING,
    FLIGHT_LARGEST_PEAK,
    FLIGHT_RANGE_ORDER,
    OrderingRow,
    phase_plane_ordering,
    reaction_ordering,
)
from telemetry.analysis.paper.results import PAPER_RESULTS, Measured, PaperResult

__all__ = [
    "FLIGHT_FASTEST_SETTLING",
    "FLIGHT_LARGEST_PEAK",
    "FLIGHT_RANGE_ORDER",
    "MIN_SETTLE_TOLERANCE_S",
    "NOT_MEASURED",
    "NOT_REPRODUCED",
    "PAPER_RESULTS",
    "REPRODUCED",
    "Comparison",
    "Measured",
    "OrderingRow",
    "PaperResult",
    "Predicted",
    "Sources",
    "compare_with_flight",
    "compare_with_plan",
    "ordered",
    "phase_plane_ordering",
    "reaction_ordering",
    "verdict",
]
