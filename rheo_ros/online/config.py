"""Tuning of the online segmenter and estimator (node parameters ``segmenter.*`` and
``estimator.*``; the defaults live in ``rheo_ros.params.DEFAULTS``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SegmenterConfig:
    """Tuning of the online segmentation (node parameters ``segmenter.*``).

    confirm: consecutive samples that confirm a change (a push starts, the stage leaves
        the hold, contact).
    plateau: flat stage samples that end the pull (their trend below ``flat_slope`` of
        the pull's velocity).
    settle_window: s of marker frames judged for the end of release.
    settle_fraction: motion over the window below this fraction of the push's largest
        marker displacement also counts as settled (noise-free data).
    min_depth: m; a push shallower than this is encoder noise, not an experiment.
    contact_force: N above the resting baseline that counts as contact (with noise,
        six times the baseline's spread when larger).
    max_release: s; a release still moving after this ends anyway (and says so).
    """

    confirm: int = 3
    plateau: int = 10
    flat_slope: float = 0.2
    settle_window: float = 5.0
    settle_fraction: float = 1e-3
    min_depth: float = 1e-4
    contact_force: float = 0.005
    max_release: float = 600.0



@dataclass(frozen=True)
class EstimatorConfig:
    """Node parameters ``estimator.*``.

    refine: follow each closed-form update by the whole-record fit of the data so far.
    undetermined_std: a parameter whose relative std exceeds this is reported as not
        determined (NaN); gamma is judged on its absolute std against ``gamma_std``.
    rate_std: the closed form's relaxation rate with a larger relative std leaves E,
        c1 and c2 undetermined (the force did not curve enough to show it).
    pre_contact: s of data kept before a push (the markers' starting positions).
    max_push_time: s; a push longer than this is dropped (memory stays bounded).
    stale_after: s (wall clock, in the node) after which a silent topic stops holding a
        phase back.
    diagnose: after release, run the model-discovery loop on the push (which effect the
        three-element model misses; ``rheo_ros.diagnosis``) and publish its verdict.
    """

    refine: bool = True
    undetermined_std: float = 0.3
    gamma_std: float = 0.05
    rate_std: float = 0.3
    pre_contact: float = 2.0
    max_push_time: float = 3600.0
    stale_after: float = 2.0
    diagnose: bool = True
