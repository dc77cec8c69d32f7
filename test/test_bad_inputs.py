"""Bad input, the whole list (issue 21, item 7): each case through the command line in this
process (``rheo_ros.app.cli.main``), asserting the exit code, the words of the one error
line (it names the file, topic or field and what is wrong), no traceback, and nothing
printed on stdout: no number from readings the analysis cannot use. One usable input (a
keep too short for the closed form) exits 0 with the reason named and no number where the
closed form has none. Then properties (hypothesis): any bytes or field values through the
bag reader's decoding, and any value of any parameter through the parameters check.

Count: ``CASES`` holds 105 distinct inputs (a command and what it is given), 104 refused
with exit 2 and one usable; none is run through the command line by another test. With
the 13 of ``test_analyze_cli.CASES`` (disjoint from these): 118 in all
(``test_the_list_is_long_enough`` holds the figures). ``Case.elsewhere`` names the 19 of
the 105 whose input another test also checks below the command line (check_params,
read_params, read_bag) or through another command: 86 are new at every level. Not
repeated here: ``rheo play --loop 0 / -1`` and ``--topics /nobody`` (test_analyze_cli),
``rheo simulate --effect nope``, ``--seed -1`` and eight parameter values
(test_package), ``rheo bag repair`` of a whole bag and ``rheo analyze`` of a killed
recording (test_nodes).

Fast on purpose (the suite's budget): bad bags are a few messages written here or the
small reference bag's files edited, and every case but the usable one fails before any
fit runs. Below the table, bad input that is usable (a right result, a warning naming the
defect): a corrupt chunk repaired and analysed with its hole named, samples out of stamp
order dropped and counted, a keep too short named in the verdict, a type not installed
skipped by ``rheo play``.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import BAGS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rheo_ros.app.cli import main
from rheo_ros.config.setup import DEFAULTS, ParamsError, Setup, check_params
from rheo_ros.io.bag import BagWriter, bag_samples, seconds_to_ns
from rheo_ros.io.checks import SampleCheck
from rheo_ros.io.errors import BagError
from rheo_ros.io.messages import (
    MARKERS_TOPIC,
    STAGE_TOPIC,
    TACTILE_TOPIC,
    TOPIC_TYPES,
    JointStateEncoder,
    MarkerArrayEncoder,
    PressureImageEncoder,
)
from rheo_ros.models.effects import catalogue

BAG = BAGS / "clean_short_keep"
SETUP = Setup(dict(DEFAULTS))        # the bags written here: 6 x 32 cells, 5 x 5 markers
IMAGE = np.zeros((SETUP.tactile.rows, SETUP.tactile.cols))
NODES = SETUP.mesh.nodes


# -- bad inputs, made under a temporary folder ---------------------------------------------

def copied(tmp: Path) -> Path:
    """The small reference bag, to damage."""
    shutil.copytree(BAG, tmp / "bag")
    return tmp / "bag"


def with_metadata(tmp: Path, edit: Callable[[dict], Any]) -> Path:
    """The reference bag with its metadata.yaml edited: ``edit`` changes the document in
    place (None) or returns the document to write instead."""
    bag = copied(tmp)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())
    new = edit(info)
    (bag / "metadata.yaml").write_text(yaml.safe_dump(info if new is None else new))
    return bag


def custom_params(value: Any) -> Callable[[dict], None]:
    """An edit of the metadata: ``value`` stored as the bag's parameters."""
    return lambda info: info["rosbag2_bagfile_information"]["custom_data"].update({"rheo_ros.params": value})


def with_mcap(tmp: Path, change: Callable[[bytes], bytes | None]) -> Path:
    """The reference bag with its .mcap file's bytes changed (None: the file removed)."""
    bag = copied(tmp)
    mcap = next(bag.glob("*.mcap"))
    data = change(mcap.read_bytes())
    if data is None:
        mcap.unlink()
    else:
        mcap.write_bytes(data)
    return bag


def metadata_a_folder(tmp: Path) -> Path:
    """The reference bag with a folder where its metadata.yaml was."""
    bag = copied(tmp)
    (bag / "metadata.yaml").unlink()
    (bag / "metadata.yaml").mkdir()
    return bag


def corrupt_chunk(tmp: Path, index: int = 3) -> tuple[Path, Any]:
    """The reference bag with 64 random bytes over the data of its chunk ``index`` (the
    fourth: 46.55-62.08 s, inside the keep): the zstd frame breaks. The bag and the chunk."""
    from test_bag_reader_units import chunks

    bag = copied(tmp)
    mcap = next(bag.glob("*.mcap"))
    offset, chunk = chunks(bag)[index]
    data = bytearray(mcap.read_bytes())
    data[offset + 80:offset + 144] = np.random.default_rng(3).bytes(64)   # past the chunk's header
    mcap.write_bytes(bytes(data))
    return bag, chunk


def with_original_in_the_way(tmp: Path) -> Path:
    """A bag with a corrupt chunk, a file already where repair keeps the original."""
    bag, _ = corrupt_chunk(tmp)
    (tmp / "clean_short_keep.mcap.damaged").write_text("an earlier repair's")
    return bag


def file_with(tmp: Path, content: str | bytes, name: str = "p.yaml") -> Path:
    f = tmp / name
    if isinstance(content, bytes):
        f.write_bytes(content)
    else:
        f.write_text(content)
    return f


def params_text(body: str) -> str:
    return "/**:\n  ros__parameters:\n" + "".join(f"    {line}\n" for line in body.splitlines())


def written(tmp: Path, n: int = 20, *, stage: Callable[[int], float] = lambda k: 0.0,
            image: Callable[[int], np.ndarray] = lambda k: IMAGE,
            markers: Callable[[int], np.ndarray] = lambda k: NODES,
            stamp: Callable[[int], float] = lambda k: 0.1 * k,
            edit: Callable[[str, int, Any], None] | None = None,
            topics: dict[str, str] | None = None) -> Path:
    """A bag of ``n`` samples per topic at 10 Hz, the stage at rest, no load, the markers
    where the parameters put them; ``stage``, ``image``, ``markers`` give sample k,
    ``stamp`` its header stamp (s; it is logged, received, at 0.1 k s), ``edit(topic, k,
    msg)`` changes a copy of the message before it is written."""
    bag = tmp / "bag"
    with BagWriter(bag, dict(DEFAULTS), topics=topics, compress=False) as w:
        joints, pressures, poses = (JointStateEncoder(w.types), PressureImageEncoder(w.types),
                                    MarkerArrayEncoder(w.types))
        encode = {STAGE_TOPIC: lambda ns, k: joints(ns, stage(k), 0.0),
                  TACTILE_TOPIC: lambda ns, k: pressures(ns, image(k)),
                  MARKERS_TOPIC: lambda ns, k: poses(ns, markers(k))}
        for k in range(n):
            ns = seconds_to_ns(stamp(k))
            for topic, conn in w.connections.items():
                raw = w.store.serialize_cdr(encode[topic](ns, k), conn.msgtype)
                if edit is not None:   # on a copy: the encoders refill one message
                    msg = w.store.deserialize_cdr(raw, conn.msgtype)
                    edit(topic, k, msg)
                    raw = w.store.serialize_cdr(msg, conn.msgtype)
                w.write_raw(topic, seconds_to_ns(0.1 * k), raw)
    return bag


def at(k: int, topic: str, field: str, value: Callable[[Any], Any]) -> Callable[[str, int, Any], None]:
    """An ``edit`` for ``written``: ``field`` of message k of ``topic`` set to ``value(msg)``."""
    return lambda t, i, msg: setattr(msg, field, value(msg)) if (t, i) == (topic, k) else None


def cell_set(value: float, cell: tuple[int, int] = (0, 7)) -> np.ndarray:
    """An unloaded image with one cell reading ``value``."""
    image = IMAGE.copy()
    image[cell] = value
    return image


def marker_set(value: float, index: int = 1) -> np.ndarray:
    """The markers at rest with coordinate ``index`` (marker index // 2, x or y) ``value``."""
    frame = NODES.copy()
    frame[index // 2, index % 2] = value
    return frame


def second_connection(tmp: Path) -> Path:
    """A second /tactile/pressure connection of another type beside the contract's."""
    with BagWriter(tmp / "bag", dict(DEFAULTS), compress=False) as w:
        w.writer.add_connection(TACTILE_TOPIC, "std_msgs/msg/String", typestore=w.store)
    return tmp / "bag"


def garbage_message(tmp: Path) -> Path:
    """/stage/joint_states carrying 8 bytes that are no JointState's CDR."""
    with BagWriter(tmp / "bag", dict(DEFAULTS), compress=False) as w:
        w.write_raw(STAGE_TOPIC, 0, b"\x00\x01\x00\x00garbage!")
    return tmp / "bag"


def uninstalled_type(tmp: Path) -> Path:
    """A bag with a topic of a type this machine has no Python package for."""
    with BagWriter(tmp / "bag", None, topics={"/thing": "no_such_msgs/msg/Thing"},
                   definitions={"no_such_msgs/msg/Thing": "int32 x\n"}, compress=False) as w:
        w.write("/thing", 0, w.store.types["no_such_msgs/msg/Thing"](x=1))
    return tmp / "bag"


def short_keep(tmp: Path, keep_time: float) -> Path:
    """The independent generator's block pushed 4 mm at 2 mm/s, held ``keep_time`` s,
    released for 10 s (uniaxial: its fit takes about a second)."""
    import generator as g

    return g.generate(tmp / "bag", seed=1, profile=g.Profile(keep_time=keep_time, release_time=10.0, depth=0.004,
                                                            velocity=0.002))


# -- the table ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Case:
    """A bad input: ``make`` builds it under a temporary folder and returns the command's
    arguments; the error line must match ``pattern`` (a regex). ``code`` 0: a usable input,
    ``pattern`` then a warning's. ``elsewhere``: another test checking the same input
    below the command line (check_params, read_bag) or through another command."""

    make: Callable[[Path], list[str]]
    pattern: str
    code: int = 2
    elsewhere: str = ""


def analyze(make: Callable[[Path], Path | str], *options: str) -> Callable[[Path], list[str]]:
    """``rheo analyze BAG --quiet`` of the bag ``make`` builds."""
    return lambda tmp: ["analyze", str(make(tmp)), "--quiet", *options]


def analyze_written(**samples: Any) -> Callable[[Path], list[str]]:
    """``rheo analyze`` of a bag ``written`` with these arguments."""
    return analyze(lambda tmp: written(tmp, **samples))


def one_bad(k0: int, bad: Any, good: Any) -> Callable[[int], Any]:
    """Sample ``k0`` bad, the others good (for ``written``)."""
    return lambda k: bad if k == k0 else good


def with_params(body: str) -> Callable[[Path], list[str]]:
    """``rheo analyze`` of the reference bag with a parameters file of ``body``."""
    return lambda tmp: ["analyze", str(BAG), "--params-file", str(file_with(tmp, params_text(body))), "--quiet"]


def params_file(content: str | bytes) -> Callable[[Path], list[str]]:
    """``rheo analyze`` of the reference bag with a parameters file holding ``content``."""
    return lambda tmp: ["analyze", str(BAG), "--params-file", str(file_with(tmp, content)), "--quiet"]


def param(field: str, rest: str) -> str:
    """The pattern of a refusal of the parameters file p.yaml naming ``field``."""
    return rf"p\.yaml: {re.escape(field)}: {rest}$"


def refused(body: str, field: str, rest: str, elsewhere: str = "") -> Case:
    """``rheo analyze`` with the parameters ``body``, refused naming ``field``."""
    return Case(with_params(body), param(field, rest), elsewhere=elsewhere)


def simulate(body: str) -> Callable[[Path], list[str]]:
    return lambda tmp: ["simulate", "--params-file", str(file_with(tmp, params_text(body))), "--out", str(tmp / "out")]


def play(make: Callable[[Path], Path | str], *options: str) -> Callable[[Path], list[str]]:
    return lambda tmp: ["play", str(make(tmp)), *options]


def info_update(**fields: Any) -> Callable[[dict], None]:
    """An edit of the metadata: these fields of rosbag2_bagfile_information set."""
    return lambda info: info["rosbag2_bagfile_information"].update(fields)


CONFIG_TABLE = "test_config_table (check_params: every float NaN and inf)"
BAG_UNITS = "test_bag_reader_units"
RANDOM = np.random.default_rng(21)
AT_REST = r"bag: /stage/joint_states: no push with a release \(the stage never let go after a pull and a keep; " \
          r"found no phase\)$"
NO_FOOTER = r"bag: cannot read bag: clean_short_keep.mcap ends at byte (\d+) without the MCAP footer"

CASES: dict[str, Case] = {
    # The bag folder and its metadata.yaml
    "bag folder missing": Case(lambda tmp: ["analyze", str(tmp / "nope"), "--quiet"],
                               r"nope: not a rosbag2 directory \(no metadata.yaml\)$"),
    "bag path is a file": Case(analyze(lambda tmp: file_with(tmp, "x", "bag")),
                               r"bag: not a rosbag2 directory \(no metadata.yaml\)$"),
    "metadata.yaml a folder": Case(analyze(lambda tmp: metadata_a_folder(tmp)),
                                   r"bag/metadata.yaml: is a directory, not a file: a rosbag2 directory's "
                                   r"metadata.yaml is a YAML file$"),
    "metadata empty": Case(analyze(lambda tmp: file_with(copied(tmp), "", "metadata.yaml").parent),
                           r"bag/metadata.yaml: no rosbag2_bagfile_information mapping$"),
    "metadata a YAML list": Case(analyze(lambda tmp: with_metadata(tmp, lambda info: [1, 2])),
                                 r"bag/metadata.yaml: no rosbag2_bagfile_information mapping$", elsewhere=BAG_UNITS),
    "metadata not YAML": Case(analyze(lambda tmp: file_with(copied(tmp), "a: [b", "metadata.yaml").parent),
                              r"bag/metadata.yaml: not YAML: ", elsewhere=BAG_UNITS),
    "bagfile information a string": Case(
        analyze(lambda tmp: with_metadata(tmp, lambda info: {"rosbag2_bagfile_information": "x"})),
        r"bag/metadata.yaml: no rosbag2_bagfile_information mapping$"),
    "custom_data a list": Case(analyze(lambda tmp: with_metadata(tmp, info_update(custom_data=[1]))),
                               r"bag/metadata.yaml: custom_data is not a mapping$", elsewhere=BAG_UNITS),
    "stored parameters a number": Case(analyze(lambda tmp: with_metadata(tmp, custom_params(42))),
                                       r"metadata.yaml: custom_data rheo_ros.params: '42' \(int\) is not a "
                                       r"parameters file's text$"),
    "stored parameters not YAML": Case(analyze(lambda tmp: with_metadata(tmp, custom_params("a: [b"))),
                                       r"metadata.yaml: custom_data rheo_ros.params: not YAML: "),
    "stored parameters a YAML list": Case(analyze(lambda tmp: with_metadata(tmp, custom_params("- 1\n- 2\n"))),
                                          r"metadata.yaml: custom_data rheo_ros.params: no '<node>: "
                                          r"ros__parameters:' section with parameters$"),
    "stored stage.depth NaN": Case(
        analyze(lambda tmp: with_metadata(tmp, custom_params(params_text("stage: {depth: .nan}")))),
        r"metadata.yaml: custom_data rheo_ros.params: stage.depth: nan; must be finite$"),
    "metadata names another .mcap": Case(
        analyze(lambda tmp: with_metadata(tmp, info_update(relative_file_paths=["other.mcap"]))),
        r"bag: cannot read bag: Some database files are missing: .*other.mcap"),
    "metadata version 99": Case(analyze(lambda tmp: with_metadata(tmp, info_update(version=99))),
                                r"bag: cannot read bag: Rosbag2 version 99 not supported"),
    "metadata says sqlite3": Case(analyze(lambda tmp: with_metadata(tmp, info_update(storage_identifier="sqlite3"))),
                                  r"bag: cannot read bag: .*clean_short_keep.mcap: file is not a database"),
    # The MCAP file
    "zero-byte MCAP": Case(analyze(lambda tmp: with_mcap(tmp, lambda data: b"")),
                           r"bag: cannot read bag: clean_short_keep.mcap is empty \(0 bytes\)$"),
    "MCAP with no footer": Case(analyze(lambda tmp: with_mcap(tmp, lambda data: data[:-200])),
                                NO_FOOTER + r": cut short \(copied in part, or its writer was killed\)$"),
    "MCAP of its magic alone": Case(analyze(lambda tmp: with_mcap(tmp, lambda data: data[:8])),
                                    NO_FOOTER.replace(r"(\d+)", "8")),
    "MCAP of random bytes": Case(analyze(lambda tmp: with_mcap(tmp, lambda data: RANDOM.bytes(len(data)))),
                                 r"bag: cannot read bag: clean_short_keep.mcap is not an MCAP file \(it does not "
                                 r"start with the MCAP magic\)$"),
    "MCAP file missing": Case(analyze(lambda tmp: with_mcap(tmp, lambda data: None)),
                              r"bag: cannot read bag: Some database files are missing: .*clean_short_keep.mcap"),
    # Messages
    "a tactile frame of another size": Case(analyze_written(image=one_bad(5, IMAGE[:, :31], IMAGE)),
                                            r"bag: /tactile/pressure: image 6 x 31 at 0.500 s, parameters say 6 x 32$"),
    "an empty tactile frame": Case(analyze_written(image=one_bad(3, IMAGE[:0, :0], IMAGE)),
                                   r"bag: /tactile/pressure: image 0 x 0 at 0.300 s, parameters say 6 x 32$"),
    "a marker frame of 24 poses": Case(analyze_written(markers=one_bad(5, NODES[:24], NODES)),
                                       r"bag: /markers/mesh: 24 markers at 0.500 s, parameters say 25$"),
    "a marker frame of no pose": Case(analyze_written(markers=one_bad(2, NODES[:0], NODES)),
                                      r"bag: /markers/mesh: 0 markers at 0.200 s, parameters say 25$"),
    "a second /tactile/pressure connection of another type": Case(
        analyze(second_connection), r"bag: /tactile/pressure: a connection of type std_msgs/msg/String; the "
                                    r"contract's is sensor_msgs/msg/Image$", elsewhere=BAG_UNITS),
    "bytes that are no JointState": Case(analyze(garbage_message),
                                         r"bag: /stage/joint_states: the message logged at 0.000 s is not a "
                                         r"sensor_msgs/msg/JointState \(Could not deserialize"),
    "a NaN reading in a frame": Case(analyze_written(image=one_bad(5, cell_set(np.nan), IMAGE)),
                                     r"bag: /tactile/pressure: 1 reading\(s\) not finite \(NaN or inf\) at 0.500 s, "
                                     r"the first at row 0, col 7$"),
    "an infinite reading in a frame": Case(analyze_written(image=one_bad(4, cell_set(np.inf, (5, 31)), IMAGE)),
                                           r"bag: /tactile/pressure: 1 reading\(s\) not finite \(NaN or inf\) at "
                                           r"0.400 s, the first at row 5, col 31$"),
    "a NaN stage position": Case(analyze_written(stage=one_bad(5, np.nan, 0.0)),
                                 r"bag: /stage/joint_states: position nan at 0.500 s is not a finite number$"),
    "a NaN marker position": Case(analyze_written(markers=one_bad(5, marker_set(np.nan, 7), NODES)),
                                  r"bag: /markers/mesh: 1 coordinate\(s\) not finite \(NaN or inf\) at 0.500 s, the "
                                  r"first at marker 3$"),
    "a first marker frame all NaN": Case(analyze_written(markers=one_bad(0, NODES * np.nan, NODES)),
                                         r"bag: /markers/mesh: 50 coordinate\(s\) not finite \(NaN or inf\) at "
                                         r"0.000 s, the first at marker 0$"),
    "header stamps all zero": Case(analyze_written(stamp=lambda k: 0.0),
                                   r"bag: /stage/joint_states: 19 of 20 header stamps are not after the one before "
                                   r"\(the latest 0.000 s\): the stamps do not advance"),
    "every header stamp twice": Case(analyze_written(stamp=lambda k: 0.1 * (k // 2)),
                                     r"bag: /stage/joint_states: 10 of 20 header stamps are not after the one before"),
    "a stage message stamped 2 s early": Case(analyze_written(stamp=lambda k: 5.0 + 0.1 * k - 2.1 * (k == 10)),
                                              r"bag: /stage/joint_states: header stamps jump back 2 s at 5.900 s "
                                              r"\(a clock jump: the record cannot be put in order\)$"),
    "one message per topic": Case(analyze_written(n=1), AT_REST),
    "a stage that never moves": Case(analyze_written(n=60), AT_REST),
    "the stage topic alone": Case(analyze_written(topics={STAGE_TOPIC: TOPIC_TYPES[STAGE_TOPIC]}),
                                  r"bag: /tactile/pressure: no messages$", elsewhere="test_bags (read_bag)"),
    "a joint not named stage": Case(analyze_written(edit=at(3, STAGE_TOPIC, "name", lambda m: ["arm"])),
                                    r"bag: /stage/joint_states: name: no joint 'stage' \(has \['arm'\]\)$"),
    "a JointState without position": Case(
        analyze_written(edit=at(3, STAGE_TOPIC, "position", lambda m: np.zeros(0))),
        r"bag: /stage/joint_states: position: missing$"),
    "an image encoded mono8": Case(analyze_written(edit=at(3, TACTILE_TOPIC, "encoding", lambda m: "mono8")),
                                   r"bag: /tactile/pressure: encoding: 'mono8', expected '32FC1'$"),
    "an image 4 bytes short": Case(analyze_written(edit=at(3, TACTILE_TOPIC, "data", lambda m: m.data[:-4])),
                                   r"bag: /tactile/pressure: data: 191 floats for 6 x 32 \(step 128\)$"),
    "an image 3 bytes short": Case(analyze_written(edit=at(3, TACTILE_TOPIC, "data", lambda m: m.data[:-3])),
                                   r"bag: /tactile/pressure: data: 765 bytes, not a whole number of 4-byte floats$"),
    "a push with a keep too short to find": Case(analyze(lambda tmp: short_keep(tmp, 0.05)),
                                                 r"bag: /stage/joint_states: the stage went 4 mm deep but never held "
                                                 r"still there for segmenter.plateau \(10 samples\): no pull ended, so "
                                                 r"no keep to identify from \(a keep too short, or none\)$"),
    # The parameters file (--params-file), each value on its own
    "specimen.height .inf": refused("specimen: {height: .inf}", "specimen.height", r"inf; must be finite",
                                    CONFIG_TABLE),
    "specimen.height 1e300": refused("specimen: {height: 1e300}", "specimen.height",
                                     r"1e\+300; must be from 0.0001 to 10 m"),
    "specimen.height negative": refused("specimen: {height: -0.08}", "specimen.height", r"-0.08; must be positive"),
    "specimen.height NaN": refused("specimen: {height: .nan}", "specimen.height", r"nan; must be finite", CONFIG_TABLE),
    "specimen.height a string": refused("specimen: {height: tall}", "specimen.height", r"expected float, got 'tall'"),
    "specimen.width 0": refused("specimen: {width: 0.0}", "specimen.width", r"0.0; must be positive"),
    "mesh.refine 400": refused("mesh: {refine: 400}", "mesh.refine", r"400 splits per element; must be at most 64"),
    "markers 100 x 100 at mesh.refine 8": refused("markers: {rows: 100, cols: 100}", "mesh.refine",
                                                  r"8 on markers.rows x markers.cols = 100 x 100 makes 628849 mesh "
                                                  r"nodes; at most 66049 fit in memory"),
    "markers.rows 400": refused("markers: {rows: 400}", "markers.rows", r"400 markers; must be at most 257"),
    "stage.depth NaN": refused("stage: {depth: .nan}", "stage.depth", r"nan; must be finite", CONFIG_TABLE),
    "stage.depth inf": refused("stage: {depth: .inf}", "stage.depth", r"inf; must be finite", CONFIG_TABLE),
    "stage.depth 0": refused("stage: {depth: 0.0}", "stage.depth", r"0.0; must be positive"),
    "stage.depth negative": refused("stage: {depth: -0.01}", "stage.depth", r"-0.01; must be positive"),
    "stage.velocity NaN": refused("stage: {velocity: .nan}", "stage.velocity", r"nan; must be finite", CONFIG_TABLE),
    "stage.velocity inf": refused("stage: {velocity: .inf}", "stage.velocity", r"inf; must be finite", CONFIG_TABLE),
    "stage.velocity negative": refused("stage: {velocity: -0.0005}", "stage.velocity", r"-0.0005; must be positive"),
    "stage.keep_time NaN": refused("stage: {keep_time: .nan}", "stage.keep_time", r"nan; must be finite", CONFIG_TABLE),
    "stage.keep_time 0": refused("stage: {keep_time: 0.0}", "stage.keep_time", r"0.0; must be positive"),
    "stage.keep_time negative": refused("stage: {keep_time: -1.0}", "stage.keep_time", r"-1.0; must be positive"),
    "stage.start_delay negative": refused("stage: {start_delay: -1.0}", "stage.start_delay",
                                          r"-1.0; must not be negative"),
    "tactile.threshold NaN": refused("tactile: {threshold: .nan}", "tactile.threshold", r"nan; must be finite",
                                     CONFIG_TABLE),
    "tactile.noise NaN": refused("tactile: {noise: .nan}", "tactile.noise", r"nan; must be finite", CONFIG_TABLE),
    "markers.noise NaN": refused("markers: {noise: .nan}", "markers.noise", r"nan; must be finite", CONFIG_TABLE),
    "markers.noise negative": refused("markers: {noise: -2.0e-5}", "markers.noise", r"-2e-05; must not be negative"),
    "tactile.rows fractional": refused("tactile: {rows: 2.5}", "tactile.rows", r"expected int, got 2.5"),
    "tactile.cols 0": refused("tactile: {cols: 0}", "tactile.cols", r"0 cells; must be at least 1",
                              "test_setup_checks"),
    "tactile.cols 1e12": refused("tactile: {cols: 1000000000000}", "tactile.cols",
                                 r"1000000000000 cells; must be at most 1024"),
    "material.gamma 0.5": refused("material: {gamma: 0.5}", "material.gamma", r"Poisson ratio 0.5 outside \(-1, 0.5\)"),
    "segmenter.confirm 0": refused("segmenter: {confirm: 0}", "segmenter.confirm", r"0 samples; must be at least 1"),
    "estimator.stale_after 0": refused("estimator: {stale_after: 0.0}", "estimator.stale_after",
                                       r"0.0; must be positive"),
    "effects.adhesion.fraction 1.5": refused("effects: {adhesion: {fraction: 1.5}}", "effects.adhesion.fraction",
                                             r"1.5; must be from 0 to 1"),
    "an unknown effect listed": refused("simulator: {effects: [gravity]}", "simulator.effects",
                                        r"unknown effect 'gravity'; known: .*"),
    "an effect listed twice": refused("simulator: {effects: [adhesion, adhesion]}", "simulator.effects",
                                      r"adhesion listed more than once"),
    "an unknown parameter name": Case(with_params("specimen: {hieght: 0.08}"),
                                      r"p\.yaml: unknown parameter\(s\): specimen.hieght$"),
    "parameters a YAML list": Case(params_file("- 1\n- 2\n"),
                                   r"p\.yaml: no '<node>: ros__parameters:' section with parameters$"),
    "ros__parameters a list": Case(params_file("/**:\n  ros__parameters: [1]\n"),
                                   r"p\.yaml: no '<node>: ros__parameters:' section with parameters$"),
    "an empty parameters file": Case(params_file(""),
                                     r"p\.yaml: no '<node>: ros__parameters:' section with parameters$"),
    "a parameters file of random bytes": Case(params_file(b"\x00\x82" + RANDOM.bytes(300)),
                                              r"p\.yaml: not text \(byte 1 is not UTF-8\)$"),
    "a parameters file that is a folder": Case(lambda tmp: ["analyze", str(BAG), "--params-file", str(tmp), "--quiet"],
                                               r": cannot read: Is a directory$"),
    # Command-line arguments and output paths
    "--add of an unknown form": Case(analyze(lambda tmp: BAG, "--add", "relaxation_branch:nope"),
                                     r"^rheo: error: effect 'relaxation_branch' has no form 'nope'; its forms: "),
    "--add of nothing": Case(analyze(lambda tmp: BAG, "--add", ""), r"^rheo: error: unknown effect ''; known: "),
    "--json into a folder that does not exist": Case(
        lambda tmp: ["analyze", str(BAG), "--json", str(tmp / "no" / "r.json"), "--quiet"],
        r"--json \S+/no/r.json: no folder \S+/no to write it in$"),
    "--json at a folder": Case(lambda tmp: ["analyze", str(BAG), "--json", str(tmp), "--quiet"],
                               r"--json \S+: is a folder$"),
    "--report at a file": Case(lambda tmp: ["analyze", str(BAG), "--report", str(file_with(tmp, "x", "r")), "--quiet"],
                               r"--report \S+/r: exists and is not a folder$"),
    # rheo simulate
    "simulate with tactile.noise NaN": Case(simulate("tactile: {noise: .nan}"),
                                            param("tactile.noise", r"nan; must be finite"), elsewhere=CONFIG_TABLE),
    "simulate with markers.noise NaN": Case(simulate("markers: {noise: .nan}"),
                                            param("markers.noise", r"nan; must be finite"), elsewhere=CONFIG_TABLE),
    "simulate a keep of 1e9 s": Case(simulate("stage: {keep_time: 1.0e9}"),
                                     r"rheo: error: stage.\*, rates.\*: a run of 1e\+09 s at these rates holds "
                                     r"[\d.e+]+ GiB of samples, more than the 4 GiB rheo simulate holds; shorten "
                                     r"stage.keep_time"),
    "simulate into a bag that exists": Case(lambda tmp: ["simulate", "--out", str(tmp)],
                                            r"exists already, not overwriting$"),
    "simulate into a folder that does not exist": Case(lambda tmp: ["simulate", "--out", str(tmp / "no" / "bag")],
                                                       r"--out \S+/no/bag: no folder \S+/no to write it in$"),
    # rheo play (each fails before DDS starts)
    "play a bag that does not exist": Case(play(lambda tmp: tmp / "nope"), r"nope: not a rosbag2 directory"),
    "play a truncated MCAP": Case(play(lambda tmp: with_mcap(tmp, lambda data: data[: len(data) // 3])), NO_FOOTER,
                                  elsewhere="test_analyze_cli (rheo analyze)"),
    "play a zero-byte MCAP": Case(play(lambda tmp: with_mcap(tmp, lambda data: b"")),
                                  r"bag: cannot read bag: clean_short_keep.mcap is empty \(0 bytes\)$"),
    "play a type not installed": Case(play(uninstalled_type),
                                      r"bag: /thing: type no_such_msgs/msg/Thing is not installed here; nothing else "
                                      r"to play$"),
    "play --rate 0": Case(play(lambda tmp: BAG, "--rate", "0"), r"argument --rate: 0 must be a finite number above 0$"),
    "play --rate nan": Case(play(lambda tmp: BAG, "--rate", "nan"),
                            r"argument --rate: nan must be a finite number above 0$"),
    "play --loop 1.5": Case(play(lambda tmp: BAG, "--loop", "1.5"), r"argument --loop: '1.5' is not a whole number$"),
    # rheo bag repair, rheo record
    "repair a folder that does not exist": Case(lambda tmp: ["bag", "repair", str(tmp / "nope")],
                                                r"nope: 0 .mcap files; a recording has one$"),
    "repair a bag whose metadata.yaml is a folder": Case(lambda tmp: ["bag", "repair", str(metadata_a_folder(tmp))],
                                                         r"bag/metadata.yaml: is a directory, not a file"),
    "repair a corrupt bag where its original would go": Case(
        lambda tmp: ["bag", "repair", str(with_original_in_the_way(tmp))],
        r"clean_short_keep.mcap.damaged: exists \(an earlier repair\?\); move it away first: the original goes "
        r"there$"),
    "repair a zero-byte recording": Case(lambda tmp: ["bag", "repair", str(file_with(tmp, b"", "x.mcap").parent)],
                                         r"x.mcap: no complete message in the stream"),
    "record into a bag that exists": Case(lambda tmp: ["record", "/stage/joint_states", "--out", str(tmp)],
                                          r"exists already, not overwriting$"),
    # Usable: the closed form has no numbers and says why; the fit's are right (about 3 s).
    "a keep of 0.3 s": Case(analyze(lambda tmp: short_keep(tmp, 0.3), "--no-discover"),
                            r"^rheo analyze: warning: closed form: E not determined: the force curved too little to "
                            r"show its relaxation rate .*; a keep long enough for the force to relax visibly "
                            r"determines it$", code=0),
}


# Warnings Python does not show a command-line user by default; any other is a line on
# stderr with its source (a numpy RuntimeWarning on garbage readings, issue 21).
HIDDEN = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)


def run_cli(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    """``rheo ARGV`` in this process: exit code (argparse's SystemExit included), stdout, and
    stderr with a line for each warning the command would have printed there."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    out = capsys.readouterr()
    shown = [f"{w.filename}:{w.lineno}: {w.category.__name__}: {w.message}\n" for w in caught
             if not issubclass(w.category, HIDDEN)]
    return code, out.out, "".join(shown) + out.err


@pytest.mark.parametrize("name", CASES)
def test_a_bad_input_is_one_line_naming_what_is_wrong(tmp_path, capsys, name):
    case = CASES[name]
    code, out, err = run_cli(case.make(tmp_path), capsys)
    assert "Traceback" not in err, err
    assert code == case.code, (code, err)
    lines = err.strip().splitlines()
    if case.code == 2:
        # One line, or argparse's usage and its line (rheo play: error: ...); nothing on stdout.
        usage = len(lines) > 1 and lines[0].startswith("usage: rheo")
        assert len(lines) == 1 or usage, err
        assert re.match(r"rheo( play)?: error: ", lines[-1]), lines[-1]
        assert re.search(case.pattern, lines[-1]), lines[-1]
        assert out == "", out
    else:
        # Usable readings: a warning names what the data leave open, the closed form prints
        # no number for it; the whole-record fit's are right (the generator's E 3.33e4 Pa).
        assert any(re.search(case.pattern, line) for line in lines), err
        assert all(line.startswith("rheo analyze: warning: ") for line in lines), err
        assert re.search(r"^closed form \(\w+\): E not determined .* gamma not determined", out, re.MULTILINE), out
        assert re.search(r"^three_element: E 3\.3[23]\d*e\+04 \+- ", out, re.MULTILINE), out


def test_the_list_is_long_enough():
    """The figures of the module's docstring: 105 here (one usable), 13 in test_analyze_cli,
    disjoint; 19 of these also checked below the command line or through another command."""
    from test_analyze_cli import CASES as ANALYZE_CASES

    assert len(CASES) == 105 and len(ANALYZE_CASES) == 13 and not set(CASES) & set(ANALYZE_CASES)
    assert sum(c.code == 0 for c in CASES.values()) == 1
    assert sum(bool(c.elsewhere) for c in CASES.values()) == 19
    assert len(CASES) - 19 + len(ANALYZE_CASES) >= 60


# -- bad input that is usable: a right result, with the defect named ------------------------

def test_a_corrupt_chunk_is_repaired_saying_what_was_lost_and_the_hole_is_named(tmp_path, capsys):
    """A whole bag one of whose chunks does not decompress: ``rheo analyze`` refuses naming
    the chunk and saying to repair; ``rheo bag repair`` rebuilds the bag from the chunks
    that read, keeps the original beside it and says how many messages per topic and
    which span were lost; the repaired bag analyses (the hole, 15.5 s inside the keep,
    leaves the parameters right) with a warning per topic naming the gap."""
    bag, chunk = corrupt_chunk(tmp_path)
    damaged = next(bag.glob("*.mcap")).read_bytes()
    span = rf"\({chunk.message_start_time * 1e-9:.3f}-{chunk.message_end_time * 1e-9:.3f} s\)"
    code, out, err = run_cli(["analyze", str(bag), "--quiet", "--no-discover"], capsys)
    assert code == 2 and out == "" and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert re.search(rf"^rheo: error: \S+/bag/clean_short_keep.mcap: the chunk at byte \d+ {span} cannot be "
                     rf"decoded .*: corrupt; `rheo bag repair \S+/bag` rebuilds the bag from the chunks that read$",
                     err.strip()), err

    code, out, err = run_cli(["bag", "repair", str(bag)], capsys)
    assert code == 0 and err == "", err
    rebuilt, lost = out.strip().splitlines()
    assert rebuilt.endswith("(the original kept as clean_short_keep.mcap.damaged and "
                            "bag.metadata.yaml.damaged beside it)"), rebuilt
    kept = {t: int(n) for n, t in re.findall(r"(\d+) on (/[\w/]+)", rebuilt.split("(")[0])}
    gone = {t: int(n) for n, t in re.findall(r"(\d+) on (/[\w/]+)", lost.split(":")[1])}
    assert re.search(rf": 1 chunk\(s\) that did not read, logged {span[2:-2]}$", lost), lost
    whole = yaml.safe_load((BAG / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert {t: kept[t] + gone[t] for t in kept} == {
        t["topic_metadata"]["name"]: t["message_count"] for t in whole["topics_with_message_count"]}
    assert all(gone.values()), lost
    assert (tmp_path / "clean_short_keep.mcap.damaged").read_bytes() == damaged   # the original, kept whole
    assert (tmp_path / "bag.metadata.yaml.damaged").read_text() == (BAG / "metadata.yaml").read_text()

    code, out, err = run_cli(["analyze", str(bag), "--quiet", "--no-discover"], capsys)
    assert code == 0 and "Traceback" not in err, err
    for topic in (STAGE_TOPIC, TACTILE_TOPIC, MARKERS_TOPIC):
        assert re.search(rf"^rheo analyze: warning: {topic}: no message for 15\.\d s \(46\.5\d\d-62\.\d\d\d s, a lost "
                         r"chunk or a sensor that stopped\): the analysis fits the samples around the gap", err,
                         re.MULTILINE), err
    assert re.search(r"^three_element: E 3\.3[23]\d*e\+04 \+- ", out, re.MULTILINE), out


def reordered(tmp: Path) -> Path:
    """The independent generator's short push (a 3 s keep) with two tactile frames' header
    stamps swapped (frames 40 and 41) and marker frame 20 logged after frame 21: one
    message of each topic arrives stamped before the one before it."""
    from rosbags.highlevel import AnyReader

    from rheo_ros.io.bag import read_params, typestore

    source = short_keep(tmp / "source", 3.0)
    rows = []
    with AnyReader([source], default_typestore=typestore()) as reader:
        counts: dict[str, int] = {}
        for conn, t, raw in reader.messages():
            k = counts[conn.topic] = counts.get(conn.topic, -1) + 1
            rows.append([conn.topic, k, t, reader.deserialize(raw, conn.msgtype)])
    frames = {(topic, k): row for row in rows for topic, k in [row[:2]]}
    a, b = frames[TACTILE_TOPIC, 40][3].header, frames[TACTILE_TOPIC, 41][3].header
    a.stamp, b.stamp = b.stamp, a.stamp
    frames[MARKERS_TOPIC, 20][2] = frames[MARKERS_TOPIC, 21][2] + 1_000_000   # logged 1 ms after the next frame
    with BagWriter(tmp / "bag", read_params(source), compress=False) as w:
        for topic, _, t, msg in sorted(rows, key=lambda row: row[2]):
            w.write(topic, t, msg)
    return tmp / "bag"


def test_samples_out_of_stamp_order_are_dropped_as_the_node_drops_them_and_counted(tmp_path, capsys):
    """Two tactile frames swapped, a marker frame logged late: the core drops the one
    stamped before its topic's latest (the node does, counting it on /diagnostics as
    "out of order"); ``rheo analyze`` says so, per topic, with the count."""
    bag = reordered(tmp_path)
    code, out, err = run_cli(["analyze", str(bag), "--quiet", "--no-discover"], capsys)
    assert code == 0 and "Traceback" not in err, err
    for topic in (TACTILE_TOPIC, MARKERS_TOPIC):
        assert f"rheo analyze: warning: {topic}: 1 message(s) stamped not after the one before (out of header-stamp " \
               "order) dropped, as the estimator node drops them" in err, err
    assert f"warning: {STAGE_TOPIC}: " not in err, err   # the stage's stamps all in order
    assert re.search(r"^three_element: E 3\.3[23]\d*e\+04 \+- ", out, re.MULTILINE), out


def test_the_verdict_names_a_keep_too_short_never_a_plain_adequate(tmp_path, capsys):
    """A keep of 0.3 s with the diagnosis on: the closed form determines nothing and an
    effect that shows in the keep (relaxation_branch) could not show; the verdict says
    "adequate" only with the keep named too short (text and JSON, the contract's keys)."""
    bag, report = short_keep(tmp_path, 0.3), tmp_path / "r.json"
    code, out, err = run_cli(["analyze", str(bag), "--quiet", "--json", str(report)], capsys)
    assert code == 0 and "Traceback" not in err, err
    short = (r"Verdict: three_element is adequate for these data\. But the keep \(0\.3 s\) was too short for the "
             r"force to relax visibly: c2 \(and E, c1, gamma\) not determined by the closed form because the keep is "
             r"too short, and relaxation_branch, which shows in the keep, could not show: adequate for the phases "
             r"recorded, not judged on the keep")
    assert re.search(short, out), out
    diagnosis = json.loads(report.read_text())["diagnosis"]
    assert re.search(short, diagnosis["evidence"]) and {"adequate", "missing_effect", "candidates"} <= set(diagnosis)
    # The node says the same (one computation: its core over the bag, /rheo/diagnosis's evidence).
    from rheo_ros.app.analyze import estimate_bag

    node: list = []
    estimate_bag(str(bag), diagnoses=node)
    assert node and node[-1].evidence.endswith(diagnosis["evidence"].split("Verdict: ", 1)[1]), node[-1].evidence


def test_play_skips_a_topic_whose_type_is_not_installed_and_plays_the_rest(tmp_path, capsys):
    """A bag of /thing (a type not installed here) and /stage/joint_states: one warning
    line naming the topic and its type, the rest played (with no type left: refused,
    ``CASES``)."""
    with BagWriter(tmp_path / "bag", None, topics={"/thing": "no_such_msgs/msg/Thing", **TOPIC_TYPES},
                   definitions={"no_such_msgs/msg/Thing": "int32 x\n"}, compress=False) as w:
        w.write("/thing", 0, w.store.types["no_such_msgs/msg/Thing"](x=1))
        w.write(STAGE_TOPIC, 1, JointStateEncoder(w.types)(1, 0.0, 0.0))
    code, out, err = run_cli(["play", str(tmp_path / "bag"), "--clock"], capsys)
    assert code == 0 and "Traceback" not in err, err
    assert err.strip() == f"rheo play: warning: {tmp_path / 'bag'}: /thing: type no_such_msgs/msg/Thing is not " \
                          "installed here: not played", err
    assert out.strip() == f"{tmp_path / 'bag'}: played 1 on /stage/joint_states, 0 on /tactile/pressure, " \
                          "0 on /markers/mesh", out


# -- properties: decoding and the parameters check ----------------------------------------

PROPERTY = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

FLOATS = st.floats(allow_nan=True, allow_infinity=True)
FLOAT32S = st.floats(allow_nan=True, allow_infinity=True, width=32)   # what an image's data can hold


def values(draw: st.DrawFn, width: int = 64) -> st.SearchStrategy[float]:
    """Floats of any kind, or (half the time) finite ones only: a message whose every value
    is finite goes on to the checks of sizes and spans."""
    return st.floats(allow_nan=False, allow_infinity=False, width=width) if draw(st.booleans()) else \
        (FLOATS if width == 64 else FLOAT32S)
STAMPS = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1))


@st.composite
def joint_states(draw: st.DrawFn, store: Any) -> Any:
    """A JointState of any names and values, the stage joint among them or not."""
    types = store.types
    sec, nanosec = draw(STAMPS)
    return types["sensor_msgs/msg/JointState"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                            frame_id=draw(st.text(max_size=4))),
        name=draw(st.lists(st.sampled_from(["stage", "arm", ""]) | st.text(max_size=4), max_size=3)),
        position=np.array(draw(st.lists(values(draw), max_size=3)), np.float64),
        velocity=np.array(draw(st.lists(FLOATS, max_size=3)), np.float64),
        effort=np.array(draw(st.lists(FLOATS, max_size=2)), np.float64))


@st.composite
def images(draw: st.DrawFn, store: Any) -> Any:
    """An Image of any size, encoding, byte order, step and data: often the contract's
    6 x 32 32FC1 with float values of any kind, else anything."""
    types = store.types
    sec, nanosec = draw(STAMPS)
    if draw(st.booleans()):
        height, width, encoding, step = 6, 32, "32FC1", 128
        data = np.array(draw(st.lists(values(draw, 32), min_size=192, max_size=192)), "<f4").view(np.uint8)
    else:
        height, width, step = draw(st.integers(0, 2**32 - 1)), draw(st.integers(0, 40)), draw(st.integers(0, 200))
        encoding = draw(st.sampled_from(["32FC1", "mono8", ""]) | st.text(max_size=6))
        data = np.frombuffer(draw(st.binary(max_size=300)), np.uint8)
    return types["sensor_msgs/msg/Image"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                            frame_id=""),
        height=min(height, 2**32 - 1), width=width, encoding=encoding, is_bigendian=draw(st.integers(0, 255)),
        step=step, data=data)


@st.composite
def pose_arrays(draw: st.DrawFn, store: Any) -> Any:
    """A PoseArray of any number of poses at any positions (25: the parameters' count)."""
    types = store.types
    sec, nanosec = draw(STAMPS)
    Point, Quaternion = types["geometry_msgs/msg/Point"], types["geometry_msgs/msg/Quaternion"]
    count = draw(st.sampled_from([25, 0, 24]) | st.integers(0, 30))
    coordinate = values(draw)
    xy = draw(st.lists(st.tuples(coordinate, coordinate), min_size=count, max_size=count))
    return types["geometry_msgs/msg/PoseArray"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                            frame_id="specimen"),
        poses=[types["geometry_msgs/msg/Pose"](position=Point(x=x, y=y, z=0.0),
                                               orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)) for x, y in xy])


MESSAGES = {STAGE_TOPIC: joint_states, TACTILE_TOPIC: images, MARKERS_TOPIC: pose_arrays}


def decoded_or_named(bag: Path, topic: str) -> None:
    """The reader's outcome on a bag of one message on ``topic``: a sample, which the
    analysis's checks (``SampleCheck``) then pass or refuse in words, or a BagError naming
    the bag and the topic. Any other exception fails the property, and so does a
    RuntimeWarning (a line of numpy's on the user's terminal)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            samples = list(bag_samples(bag))
        except BagError as exc:
            assert str(exc).startswith(f"{bag}: {topic}: "), str(exc)
            return
        [(_, t, value)] = samples
        problem = SampleCheck(SETUP).problem(topic, t, value)
    assert problem is None or isinstance(problem, str)


def one_message_bag(tmp: Path, topic: str, raw: bytes) -> Path:
    bag = tmp / f"bag{len(list(tmp.iterdir()))}"
    with BagWriter(bag, None, compress=False) as w:
        w.write_raw(topic, 0, raw)
    return bag


@PROPERTY
@given(topic=st.sampled_from(list(MESSAGES)), raw=st.binary(max_size=200))
def test_any_bytes_on_a_measurement_topic_decode_or_are_named(tmp_path, topic, raw):
    """Bytes that are no message of the topic's type: a BagError naming the topic and the
    type (rosbags raised struct errors, IndexError, UnicodeDecodeError: one line said
    "cannot read bag" without the topic), or whatever they happen to decode to, checked."""
    decoded_or_named(one_message_bag(tmp_path, topic, raw), topic)


@PROPERTY
@given(data=st.data(), topic=st.sampled_from(list(MESSAGES)))
def test_any_field_values_decode_or_are_named(tmp_path, data, topic):
    """A well-formed message of the contract's type with any field values (NaN, inf,
    sizes that do not add up, another encoding, no stage joint, any stamp)."""
    from rheo_ros.io.bag import typestore

    store = typestore()
    msg = data.draw(MESSAGES[topic](store))
    decoded_or_named(one_message_bag(tmp_path, topic, store.serialize_cdr(msg, TOPIC_TYPES[topic])), topic)


SPECIAL = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e300, -1e300, 5e-324, 0.5, 2**53,
                           10**30, -10**30, 0, -1, 1, True, False, None, "", "nan", "1e3", [], [""], {}])
ANY_VALUE = (SPECIAL | st.floats(allow_nan=True, allow_infinity=True) | st.integers(-10**40, 10**40)
             | st.text(max_size=8) | st.lists(st.sampled_from(["", *catalogue(), "nope"]) | st.text(max_size=6),
                                              max_size=3))


@PROPERTY
@given(name=st.sampled_from(list(DEFAULTS)), value=ANY_VALUE)
def test_any_value_of_any_parameter_is_refused_naming_it_or_makes_a_setup(name, value):
    """check_params on one parameter set to anything: a ParamsError naming that parameter
    (a value of another type, out of its range, or one that cannot work with the others'
    defaults), or parameters from which everything the analysis and the nodes build is
    built without error."""
    try:
        params = check_params({name: value}, "p.yaml")
    except ParamsError as exc:
        assert str(exc).startswith("p.yaml: ") and name in str(exc), (name, value, str(exc))
        return
    setup = Setup(params)
    _ = (setup.mesh.refined(params["mesh.refine"]), setup.tactile.segment_edges, setup.profile, setup.model(),
         setup.camera, setup.segmenter_config(), setup.estimator_config(), SampleCheck(setup))


@PROPERTY
@given(effect=st.sampled_from(catalogue()), field=st.sampled_from(["form", "time", "stiffness", "fraction", "nope"]),
       value=ANY_VALUE)
def test_any_value_of_a_listed_effects_parameter_is_refused_naming_it_or_makes_a_setup(effect, field, value):
    """The open ``effects.<id>.*`` namespace with the effect listed (the simulator builds
    it): a ParamsError naming ``effects.<id>``, or a model built."""
    name = f"effects.{effect}.{field}"
    try:
        params = check_params({"simulator.effects": [effect], name: value}, "p.yaml")
    except ParamsError as exc:
        assert str(exc).startswith("p.yaml: ") and f"effects.{effect}" in str(exc), (name, value, str(exc))
        return
    assert Setup(params).model().effects


def test_a_hole_is_said_on_the_pushes_whose_data_it_touches():
    """A hole in a topic's stamps is a warning on each push whose samples it falls among
    (a bag of several pushes: not on the others); a whole-bag note on every push."""
    from rheo_ros.app.analyze import SampleNote, stamp_gaps

    [hole] = stamp_gaps(np.r_[np.arange(0.0, 10.0, 0.02), np.arange(15.0, 30.0, 0.02)])
    assert hole.span == pytest.approx((9.98, 15.0)) and "no message for 5.02 s" in hole.text
    assert hole.touches(0.0, 12.0) and hole.touches(14.0, 40.0) and not hole.touches(15.5, 40.0)
    assert not hole.touches(0.0, 9.9) and SampleNote("whole bag").touches(100.0, 200.0)
    assert stamp_gaps(np.arange(0.0, 10.0, 0.02)) == []   # sampled throughout: none
