"""The parameters file: a standard ROS 2 parameters file (``/**: ros__parameters:``).

Nodes read it with ``--ros-args --params-file FILE``, the CLI with ``--params-file
FILE``; a bag written by the package carries its text in the metadata. Nested keys
are the dotted ROS parameter names (``specimen.width``). Every name's default, help
and per-value check is its row in ``rheo_ros.config.table.PARAMETERS``;
``config/rheo_ros.yaml`` mirrors the table with comments.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rheo_ros.config.table import MAX_NODES, PARAMETERS, RENAMED
from rheo_ros.config.tuning import EstimatorConfig, SegmenterConfig
from rheo_ros.experiment import StageProfile
from rheo_ros.fe.dynamic import DynamicFE
from rheo_ros.fe.mesh import Boundary, Mesh
from rheo_ros.fe.quasistatic import Dynamics, QuasiStaticFE
from rheo_ros.models.effects import Effect, Model, catalogue, effect_class
from rheo_ros.models.elements import Element, three_element
from rheo_ros.record import Record
from rheo_ros.sensors import MarkerCamera, SensorReading, TactileArray, TactileReadout, marker_noise, read_sensor

FORWARD_MODELS_KEPT = 4
_FORWARD_MODELS: dict[tuple, QuasiStaticFE] = {}   # Setup.forward_model's, by geometry

# Derived from the table (other modules import these names).
DEFAULTS: dict[str, Any] = {p.name: p.default for p in PARAMETERS}
PARAM_HELP: dict[str, str] = {p.name: p.help for p in PARAMETERS}


class _Loader(yaml.SafeLoader):
    """YAML as ROS 2 reads it: ``3.33e4`` is a float (PyYAML's YAML 1.1 wants ``3.33e+4``)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                |[-+]?\.(?:inf|Inf|INF)
                |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


class ParamsError(ValueError):
    """A parameters file cannot be used; the message names the file and the parameter."""


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def parse_params(text: str, source: str = "<text>", recorded: bool = False) -> dict[str, Any]:
    """Flat, checked parameters (defaults filled in) from a ROS 2 parameters file's text.

    Every ``<node>: ros__parameters:`` section is read, in file order (later ones
    win), so a file with ``/**`` and per-node sections gives the CLI what the nodes
    together see. ``recorded``: the parameters a bag was recorded with, which say how it
    was made: effects the simulator ran that this installation does not know (a plugin
    the recording lab had) are left out with their values; an analysis does not read
    them, and refusing the bag for them would refuse data for how it was made.
    """
    try:
        doc = yaml.load(text, Loader=_Loader) or {}
    except yaml.YAMLError as exc:
        raise ParamsError(f"{source}: not YAML: {str(exc).splitlines()[0]}") from None
    sections = [v["ros__parameters"] for v in doc.values()
                if isinstance(v, Mapping) and isinstance(v.get("ros__parameters"), Mapping)] if isinstance(doc, Mapping) else []
    if not sections:
        raise ParamsError(f"{source}: no '<node>: ros__parameters:' section with parameters")
    given: dict[str, Any] = {}
    for section in sections:
        given.update(flatten(section))
    listed = given.get("simulator.effects")
    if recorded and isinstance(listed, list):
        known = set(catalogue())
        unknown = {e for e in listed if isinstance(e, str) and e and e not in known}
        given = {k: v for k, v in given.items() if not any(k.startswith(f"effects.{e}.") for e in unknown)}
        given["simulator.effects"] = [e for e in listed if e not in unknown] or [""]
    return check_params(given, source)


def check_params(given: Mapping[str, Any], source: str = "<parameters>") -> dict[str, Any]:
    """Defaults filled in, types checked (an integer is taken for a float), each value
    checked on its own (the table's checks), then together by building everything
    from them (``Setup.check``)."""
    # Renamed parameters: files and bags written under the old name still read.
    given = {RENAMED.get(k, k): v for k, v in given.items()}
    unknown = sorted(k for k in given if k not in DEFAULTS and not k.startswith("effects."))
    if unknown:
        raise ParamsError(f"{source}: unknown parameter(s): {', '.join(unknown)}")
    params = {**DEFAULTS, **given}
    if params["geometry"] == "uniaxial":
        # The block's faces are frictionless by definition: that is its default, and
        # a bonded face given for it is refused when the mesh is built (Setup.check).
        params.update({k: "frictionless" for k in ("boundary.bottom", "boundary.top") if k not in given})
    for key, default in DEFAULTS.items():
        value = params[key]
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            params[key] = value = float(value)
        if isinstance(default, list):
            ok = isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)
            params[key] = list(value) if ok else value
        else:
            ok = type(value) is type(default)
        if not ok:
            raise ParamsError(f"{source}: {key}: expected {type(default).__name__}, got {value!r}")
    for parameter in PARAMETERS:
        refusal = parameter.refusal(params[parameter.name])
        if refusal:
            raise ParamsError(f"{source}: {refusal}")
    Setup(params).check(source)
    return params


def load_params(path: str | Path | None) -> dict[str, Any]:
    """Parameters from a file, or the defaults when ``path`` is None."""
    if path is None:
        return dict(DEFAULTS)
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ParamsError(f"{path}: not text (byte {exc.start} is not UTF-8)") from None
    return parse_params(text, str(path))


def params_yaml(params: Mapping[str, Any]) -> str:
    """A parameters file's text for flat ``params`` (stored in the bags we write)."""
    tree: dict[str, Any] = {}
    for key, value in params.items():
        node = tree
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return yaml.safe_dump({"/**": {"ros__parameters": tree}}, sort_keys=False)


@dataclass(frozen=True)
class Setup:
    """Everything a simulation or an analysis needs, built from flat parameters."""

    params: dict[str, Any]

    def check(self, source: str = "<parameters>") -> None:
        """Build every part once; a value that cannot work with the others raises
        ParamsError naming it. Each value on its own is the table's to check
        (``check_params``, before this)."""
        p = self.params
        for rate in ("rates.tactile", "rates.markers"):
            ratio = p["rates.stage"] / p[rate]
            if not np.isfinite(ratio) or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise ParamsError(f"{source}: {rate}: {p[rate]} Hz must divide rates.stage ({p['rates.stage']} Hz): "
                                  "the simulator samples on the stage's grid")
        for refine in ("mesh.refine", "simulator.refine"):
            nodes = ((p["markers.rows"] - 1) * p[refine] + 1) * ((p["markers.cols"] - 1) * p[refine] + 1)
            if nodes > MAX_NODES:
                raise ParamsError(f"{source}: {refine}: {p[refine]} on markers.rows x markers.cols = "
                                  f"{p['markers.rows']} x {p['markers.cols']} makes {nodes} mesh nodes; at most "
                                  f"{MAX_NODES} fit in memory")
        try:
            _ = (self.mesh, self.tactile, self.profile, self.effects())
            self.mesh.refined(p["mesh.refine"])
            self.mesh.stiffness(self.gamma)
        except (ValueError, KeyError) as exc:
            raise ParamsError(f"{source}: {exc}") from None
        if p["stage.depth"] >= p["specimen.height"]:
            raise ParamsError(f"{source}: stage.depth: {p['stage.depth']} m is not less than specimen.height "
                              f"({p['specimen.height']} m): the stage cannot push through the specimen")
        self._check_segments(source)

    def _check_segments(self, source: str) -> None:
        """Every bottom node needs a tactile column: its force is read back from its segment."""
        tactile = self.tactile
        if tactile.cols < tactile.nodes:
            raise ParamsError(f"{source}: tactile.cols: {tactile.cols} columns for {tactile.nodes} segments "
                              f"(one per bottom marker, markers.cols); must be at least {tactile.nodes}")
        empty = np.flatnonzero(tactile.columns_per_segment == 0)
        if empty.size:  # cannot happen with the nearest-node split, but a split that changes must not pass silently
            raise ParamsError(f"{source}: tactile.cols: {tactile.cols} columns leave segment(s) "
                              f"{', '.join(f'P{i + 1}' for i in empty)} without a column; "
                              f"each of the {tactile.nodes} segments needs one")

    # Built once (the parameters do not change): the node reads the tactile array's
    # segments for every image, and a new array per message rebuilt them each time.
    @cached_property
    def mesh(self) -> Mesh:
        p = self.params
        return Mesh.build(p["geometry"], p["specimen.width"], p["specimen.height"], p["specimen.thickness"],
                          rows=p["markers.rows"], cols=p["markers.cols"],
                          boundary=Boundary(p["boundary.bottom"], p["boundary.top"]))

    def segment_edges(self, refine: int) -> np.ndarray | None:
        """The tactile segments' edges for a mesh refined ``refine`` times; None at 1
        (the marker grid's bottom nodes' reactions are the segment forces, as in the paper)."""
        return self.tactile.segment_edges if refine > 1 else None

    def dynamic_fe(self, rheology: Element) -> DynamicFE:
        """The simulator's FE model (``simulator.refine``)."""
        p = self.params
        return DynamicFE(self.mesh, rheology, self.gamma, density=p["material.density"], omega=p["simulator.omega"],
                         refine=p["simulator.refine"], segment_edges=self.segment_edges(p["simulator.refine"]))

    def forward_model(self) -> QuasiStaticFE:
        """The identification's forward model: the marker grid refined ``mesh.refine``
        times; beyond 1, each tactile segment's force integrated over its columns.

        One per geometry in a process, shared by every analysis, fit and node there: what
        it caches (solved shapes, the implied-force table, the finer meshes' solves) are
        functions of the geometry and the ratio alone, and cost up to a second each. Its
        ``dynamics`` (``material.density``, ``simulator.omega``) give the floor of a
        record the data show noise-free (``QuasiStaticFE.dynamic_predict``)."""
        refine = self.params["mesh.refine"]
        edges = self.segment_edges(refine)
        m = self.mesh
        dynamics = Dynamics(density=self.params["material.density"], omega=self.params["simulator.omega"])
        key = (m.geometry, m.width, m.height, m.thickness, m.rows, m.cols, m.boundary, refine,
               None if edges is None else tuple(edges.tolist()), dynamics)
        if key not in _FORWARD_MODELS:
            if len(_FORWARD_MODELS) >= FORWARD_MODELS_KEPT:
                del _FORWARD_MODELS[next(iter(_FORWARD_MODELS))]
            _FORWARD_MODELS[key] = QuasiStaticFE(m, refine, edges, dynamics=dynamics)
        return _FORWARD_MODELS[key]

    @cached_property
    def tactile(self) -> TactileArray:
        p = self.params
        return TactileArray(rows=p["tactile.rows"], cols=p["tactile.cols"], width=p["specimen.width"],
                            depth=p["specimen.thickness"], nodes=self.mesh.cols,
                            noise=p["tactile.noise"], resolution=p["tactile.resolution"],
                            threshold=p["tactile.threshold"])

    def record(self, stage_t: np.ndarray, stage_depth: np.ndarray, tactile_t: np.ndarray, images: np.ndarray,
               marker_t: np.ndarray, markers: np.ndarray, source: str = "<memory>") -> Record:
        """The ``Record`` of these sensor outputs: tactile images (T, rows, cols) in Pa
        summed into segment forces, with the sensor the images show (``sensor``).

        Raises:
            RecordError: the samples do not make a record (names the field).
        """
        readout = self.readout()
        readout.add(images, tactile_t)
        sensor, forces = self.sensor(readout, self.tactile.nodal_forces(images), tactile_t, markers)
        return Record(mesh=self.mesh, stage_t=stage_t, stage_depth=stage_depth, force_t=tactile_t,
                      force=forces, marker_t=marker_t, markers=markers, source=source, sensor=sensor)

    def readout(self) -> TactileReadout:
        """An empty readout of this array's frames (``sensor`` reads it)."""
        return TactileReadout(segment=self.tactile.segment)

    def sensor(self, readout: TactileReadout, sums: np.ndarray, t: np.ndarray,
               markers: np.ndarray) -> tuple[SensorReading, np.ndarray]:
        """The sensor as these readings show it (``sensors.read_sensor``): the tactile
        readings' ``readout``, the segment sums (T, nodes) in N (``nodal_forces``) at
        stamps ``t`` (s) and the marker frames (T, N, 2) they came with; and the segment
        forces a record holds, the dead cells left out from when they died
        (``TactileArray.segment_forces``). A parameter counts as
        stated when it differs from its default (a ROS node cannot tell a default from a
        value set to it)."""
        given = frozenset(k for k in ("tactile.threshold", "tactile.resolution", "tactile.noise", "markers.noise")
                          if self.params[k] != DEFAULTS[k])
        marker_std = marker_noise(markers)[0] if len(markers) else float("nan")
        sensor = read_sensor(self.tactile, readout, sums, marker_std, self.params["markers.noise"], given)
        return sensor, sensor.tactile.segment_forces(sums, t)

    @property
    def camera(self) -> MarkerCamera:
        return MarkerCamera(noise=self.params["markers.noise"])

    @property
    def profile(self) -> StageProfile:
        p = self.params
        push = StageProfile(depth=p["stage.depth"], velocity=p["stage.velocity"], keep_time=p["stage.keep_time"],
                            start_delay=p["stage.start_delay"], release_time=p["stage.release_time"],
                            retract_speed=p["stage.retract_speed"])
        return StageProfile.repeated(push, p["stage.pushes"], p["stage.pause"])

    @property
    def effect_ids(self) -> tuple[str, ...]:
        return tuple(e for e in self.params["simulator.effects"] if e)

    def effects(self) -> tuple[Effect, ...]:
        twice = sorted({e for e in self.effect_ids if self.effect_ids.count(e) > 1})
        if twice:   # one set of effects.<id>.* for each: a second would only double the first
            raise ParamsError(f"simulator.effects: {', '.join(twice)} listed more than once")
        out = []
        for effect_id in self.effect_ids:
            prefix = f"effects.{effect_id}."
            values = {k[len(prefix):]: v for k, v in self.params.items() if k.startswith(prefix)}
            form = values.pop("form", None)   # effects.<id>.form: one of the family's forms (default: its first)
            try:
                effect_class(effect_id)
            except KeyError as exc:   # a listed id the catalogue does not hold
                raise ParamsError(f"simulator.effects: {exc.args[0]}") from None
            try:
                cls = effect_class(effect_id, form)
            except KeyError as exc:
                raise ParamsError(f"{prefix}form: {exc.args[0]}") from None
            try:
                # The table's defaults are the default form's fields: another form (held
                # adhesion, no time) leaves those it has not; a value set for one is refused.
                own = {f.name for f in fields(cls)}
                values = {k: v for k, v in values.items() if k in own or v != DEFAULTS.get(prefix + k, object())}
                out.append(cls(**values))
            except (TypeError, KeyError) as exc:
                raise ParamsError(f"effects.{effect_id}: {exc}") from None
            if out[-1].nonlinear_spring:
                raise ParamsError(f"effects.{effect_id}.form: {out[-1].form!r} makes the Voigt spring nonlinear; "
                                  f"the FE simulator's material is linear (the analysis fits this form)")
        return tuple(out)

    def model(self) -> Model:
        p = self.params
        return Model(three_element(p["material.E"], p["material.c1"], p["material.c2"]), self.effects())

    def segmenter_config(self) -> SegmenterConfig:
        return SegmenterConfig(**{f.name: self.params[f"segmenter.{f.name}"] for f in fields(SegmenterConfig)})

    def estimator_config(self) -> EstimatorConfig:
        return EstimatorConfig(**{f.name: self.params[f"estimator.{f.name}"] for f in fields(EstimatorConfig)})

    @property
    def gamma(self) -> float:
        return self.params["material.gamma"]
