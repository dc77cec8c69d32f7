"""Tuning of the online segmenter and estimator: the node parameters ``segmenter.*`` and
``estimator.*`` as dataclasses, one field per parameter of the same name. What each
means and its default are its row in ``rheo_ros.config.table.PARAMETERS``."""

from __future__ import annotations

from dataclasses import dataclass

from rheo_ros.config.table import default


@dataclass(frozen=True)
class SegmenterConfig:
    """Tuning of the online segmentation: field ``x`` is the parameter ``segmenter.x``."""

    confirm: int = default("segmenter.confirm")
    plateau: int = default("segmenter.plateau")
    flat_slope: float = default("segmenter.flat_slope")
    settle_window: float = default("segmenter.settle_window")
    settle_fraction: float = default("segmenter.settle_fraction")
    min_depth: float = default("segmenter.min_depth")
    contact_force: float = default("segmenter.contact_force")
    max_release: float = default("segmenter.max_release")


@dataclass(frozen=True)
class EstimatorConfig:
    """Tuning of the online identification: field ``x`` is the parameter ``estimator.x``
    (the node's own ``estimator.diagnostics_period`` and ``estimator.closed_form_priority``
    are not the core's)."""

    fit: bool = default("estimator.fit")
    undetermined_std: float = default("estimator.undetermined_std")
    gamma_std: float = default("estimator.gamma_std")
    rate_std: float = default("estimator.rate_std")
    pre_contact: float = default("estimator.pre_contact")
    max_push_time: float = default("estimator.max_push_time")
    stale_after: float = default("estimator.stale_after")
    release_interval: float = default("estimator.release_interval")
    diagnose: bool = default("estimator.diagnose")
