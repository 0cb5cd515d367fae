"""Evaluation: the evidence that a synthetic model is fit for testing a lander.

Slopes and roughness of DEMs (:mod:`evaluation.slope`, :mod:`evaluation.spectrum`,
:mod:`evaluation.compare`), slopes of asteroid models relative to the radial direction and to
gravity (:mod:`evaluation.meshslope`, :mod:`evaluation.gravity`), Harris feature tracking
scored against the renderer's truth (:mod:`evaluation.tracking`), and figures and
self-contained validation reports (:mod:`evaluation.figures`, :mod:`evaluation.report`,
:mod:`evaluation.cli`). Whether terrain is lunar at all is judged by published statistics
(:mod:`evaluation.lunar_stats`, :mod:`evaluation.validate`,
:mod:`evaluation.validate_report`).
"""

from evaluation.compare import (
    Comparison,
    SlopeMapAgreement,
    check_same_crs,
    compare_dems,
    compare_slope_maps,
    ks_distance,
)
from evaluation.gravity import Polyhedron, centrifugal, coarsen, polyhedron_field
from evaluation.meshslope import MeshSlopes, SlopeAreaHistogram, Spin, load_body, mesh_slopes
from evaluation.report import Report, load_thresholds, write_report
from evaluation.slope import (
    SlopeDistribution,
    cumulative_distribution,
    horn,
    horn_aspect,
    horn_slope,
    matched_baseline,
    resample,
    slope_distribution,
    stack_distributions,
)
from evaluation.spectrum import (
    HurstFit,
    RadialSpectrum,
    fit_hurst,
    fractional_brownian_surface,
    radial_spectrum,
)
from evaluation.tracking import ScoredTracks, TrackerSettings, Tracks, score, track
from evaluation.validate import Validation, validate_dem, validate_stack

__all__ = [
    "Comparison",
    "HurstFit",
    "MeshSlopes",
    "Polyhedron",
    "RadialSpectrum",
    "Report",
    "ScoredTracks",
    "SlopeAreaHistogram",
    "SlopeDistribution",
    "SlopeMapAgreement",
    "Spin",
    "TrackerSettings",
    "Tracks",
    "Validation",
    "centrifugal",
    "check_same_crs",
    "coarsen",
    "compare_dems",
    "compare_slope_maps",
    "cumulative_distribution",
    "fit_hurst",
    "fractional_brownian_surface",
    "horn",
    "horn_aspect",
    "horn_slope",
    "ks_distance",
    "load_body",
    "load_thresholds",
    "matched_baseline",
    "mesh_slopes",
    "polyhedron_field",
    "radial_spectrum",
    "resample",
    "score",
    "slope_distribution",
    "stack_distributions",
    "track",
    "validate_dem",
    "validate_stack",
    "write_report",
]
