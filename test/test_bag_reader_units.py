"""The bag reader (``rheo_ros.io.bag``) on the small reference bag ``table_I_short`` (632 kB,
read in about half a second) and on tiny bags written here: what it decodes, and each
refusal naming its file and topic. Mutation testing runs these (``./tasks mutation``)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from rheo_ros.io.bag import (
    PARAMS_KEY,
    BagWriter,
    bag_samples,
    message_definitions,
    read_bag,
    read_params,
    seconds_to_ns,
    write_run,
)
from rheo_ros.io.errors import BagError
from rheo_ros.io.messages import MARKERS_TOPIC, STAGE_TOPIC, TACTILE_TOPIC, TOPIC_TYPES

BAG = Path(__file__).resolve().parents[1] / "bags" / "table_I_short"


@pytest.fixture(scope="module")
def contents():
    return read_bag(BAG)


def test_the_reference_bag_decodes_into_its_record(contents):
    rec, params = contents.record, contents.params
    assert params == read_params(BAG)
    assert params["stage.depth"] == 0.5 and params["geometry"] == "uniaxial"
    assert rec.source == str(BAG)
    # 100 Hz stage, 50 Hz tactile, 10 Hz markers over 1 + 20 + 20 + 60 s.
    assert rec.stage_t.size == 10101 and rec.force_t.size == 5051 and rec.marker_t.size == 1011
    for t in (rec.stage_t, rec.force_t, rec.marker_t):
        assert t[0] == 0.0 and t[-1] == pytest.approx(101.0) and np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(contents.tactile_t, rec.force_t)
    assert contents.tactile.shape == (5051, 6, 32) and rec.markers.shape == (1011, 25, 2)
    assert rec.stage_depth.max() == pytest.approx(0.5) and rec.stage_depth[0] == 0.0
    assert contents.stage_velocity.shape == rec.stage_depth.shape
    assert contents.stage_velocity.max() == pytest.approx(0.025)
    p = rec.profile()
    assert p.t_pull_start == pytest.approx(1.0, abs=0.01) and p.pull_time == pytest.approx(20.0, abs=0.02)
    np.testing.assert_allclose(rec.markers[0], rec.mesh.nodes, atol=1e-12)
    assert rec.force[:, :].sum(axis=1).max() > 0


def test_samples_come_in_recorded_order_with_header_stamps(contents):
    samples = list(bag_samples(BAG))
    kinds = [s for s, _, _ in samples]
    assert kinds.count("stage") == 10101 and kinds.count("image") == 5051 and kinds.count("markers") == 1011
    stage = [(t, v) for s, t, v in samples if s == "stage"]
    np.testing.assert_array_equal([t for t, _ in stage], contents.record.stage_t)
    np.testing.assert_array_equal([v for _, v in stage], contents.record.stage_depth)
    image = next(v for s, _, v in samples if s == "image")
    np.testing.assert_array_equal(image, contents.tactile[0])
    markers = [v for s, _, v in samples if s == "markers"]
    np.testing.assert_array_equal(markers[-1], contents.record.markers[-1])
    stamps = [t for _, t, _ in samples]
    assert stamps == sorted(stamps)


def test_params_are_read_from_the_metadata_or_refused(tmp_path):
    with pytest.raises(BagError, match=r"metadata.yaml: cannot read: No such file or directory"):
        read_params(tmp_path)
    meta = tmp_path / "metadata.yaml"
    meta.write_text("a: [b")
    with pytest.raises(BagError, match=r"metadata.yaml: not YAML: "):
        read_params(tmp_path)
    meta.write_text("- 1\n")
    with pytest.raises(BagError, match=r"metadata.yaml: no rosbag2_bagfile_information mapping"):
        read_params(tmp_path)
    meta.write_text(yaml.safe_dump({"rosbag2_bagfile_information": [1]}))
    with pytest.raises(BagError, match=r"no rosbag2_bagfile_information mapping"):
        read_params(tmp_path)
    meta.write_text(yaml.safe_dump({"rosbag2_bagfile_information": {"custom_data": [1]}}))
    with pytest.raises(BagError, match=r"metadata.yaml: custom_data is not a mapping"):
        read_params(tmp_path)
    meta.write_text(yaml.safe_dump({"rosbag2_bagfile_information": {"custom_data": None}}))
    assert read_params(tmp_path) is None
    meta.write_text(yaml.safe_dump({"rosbag2_bagfile_information": {"version": 9}}))
    assert read_params(tmp_path) is None
    meta.write_text(yaml.safe_dump({"rosbag2_bagfile_information": {"custom_data": {PARAMS_KEY: ""}}}))
    assert read_params(tmp_path) is None


def test_read_bag_refuses_what_is_not_a_bag_of_the_contract(tmp_path, contents):
    with pytest.raises(BagError, match=r"not a rosbag2 directory \(no metadata.yaml\)"):
        read_bag(tmp_path)
    copy = tmp_path / "copy"
    shutil.copytree(BAG, copy)
    info = yaml.safe_load((copy / "metadata.yaml").read_text())
    info["rosbag2_bagfile_information"]["custom_data"] = {}
    (copy / "metadata.yaml").write_text(yaml.safe_dump(info))
    with pytest.raises(BagError, match=r"copy: no parameters in the bag's metadata; give --params-file"):
        read_bag(copy)
    # Given the parameters, the same bag reads as before.
    again = read_bag(copy, params=contents.params)
    np.testing.assert_array_equal(again.record.force, contents.record.force)
    wrong = {**contents.params, "markers.rows": 4}
    with pytest.raises(BagError, match=r"/markers/mesh: 25 markers, parameters say 20"):
        read_bag(copy, params=wrong)
    for mcap in copy.glob("*.mcap"):
        mcap.write_bytes(mcap.read_bytes()[:2000])
    with pytest.raises(BagError, match=r"copy: cannot read bag: "):
        read_bag(copy, params=contents.params)
    with pytest.raises(BagError, match=r"copy: cannot read bag: "):
        list(bag_samples(copy))


def run_of(contents, n=30):
    rec = contents.record
    return SimpleNamespace(stage_t=rec.stage_t[:n], stage_depth=rec.stage_depth[:n],
                           stage_velocity=contents.stage_velocity[:n], tactile_t=contents.tactile_t[:n],
                           tactile=contents.tactile[:n], marker_t=rec.marker_t[:n], markers=rec.markers[:n])


def test_a_written_run_reads_back(tmp_path, contents):
    run = run_of(contents)
    counts = write_run(run, contents.params, tmp_path / "b")
    assert counts == {STAGE_TOPIC: 30, TACTILE_TOPIC: 30, MARKERS_TOPIC: 30}
    back = read_bag(tmp_path / "b")
    assert back.params == contents.params
    np.testing.assert_array_equal(back.record.stage_t, run.stage_t)
    np.testing.assert_array_equal(back.record.stage_depth, run.stage_depth)
    np.testing.assert_array_equal(back.stage_velocity, run.stage_velocity)
    np.testing.assert_array_equal(back.tactile, run.tactile)
    np.testing.assert_array_equal(back.record.marker_t, run.marker_t)
    np.testing.assert_allclose(back.record.markers, run.markers, rtol=1e-6)
    # In stamp order, stage before tactile before markers at one stamp.
    order = [s for s, _, _ in bag_samples(tmp_path / "b")]
    assert order[:3] == ["stage", "image", "markers"]


def test_missing_topics_and_wrong_image_sizes_are_named(tmp_path, contents):
    run = run_of(contents, 5)
    with BagWriter(tmp_path / "no_markers", contents.params, topics={STAGE_TOPIC: TOPIC_TYPES[STAGE_TOPIC]},
                   compress=False) as w:
        from rheo_ros.io.messages import JointStateEncoder
        enc = JointStateEncoder(w.types)
        for t, d, v in zip(run.stage_t, run.stage_depth, run.stage_velocity):
            w.write(STAGE_TOPIC, seconds_to_ns(t), enc(seconds_to_ns(t), d, v))
    with pytest.raises(BagError, match=r"no_markers: /tactile/pressure: no messages"):
        read_bag(tmp_path / "no_markers")
    small = SimpleNamespace(**{**vars(run), "tactile": run.tactile[:, :3, :]})
    write_run(small, contents.params, tmp_path / "small")
    with pytest.raises(BagError, match=r"/tactile/pressure: images \(3, 32\), parameters say 6 x 32"):
        read_bag(tmp_path / "small")


def test_a_contract_topic_of_another_type_is_named(tmp_path, contents):
    """A second connection on /tactile/pressure of another type (issue 21: decoded as an
    image, a traceback): refused in one line naming the topic and both types."""
    with BagWriter(tmp_path / "two_types", contents.params, compress=False) as w:
        w.writer.add_connection(TACTILE_TOPIC, "std_msgs/msg/String", typestore=w.store)
    with pytest.raises(BagError, match=r"two_types: /tactile/pressure: a connection of type std_msgs/msg/String; "
                                       r"the contract's is sensor_msgs/msg/Image"):
        read_bag(tmp_path / "two_types")


def test_seconds_to_ns_rounds():
    assert seconds_to_ns(1.0000000004) == 1_000_000_000 and seconds_to_ns(0.0000000006) == 1
    assert seconds_to_ns(2.5) == 2_500_000_000


def test_message_definitions_include_the_types_they_use():
    defs = message_definitions(["sensor_msgs/msg/JointState"])
    assert "std_msgs/msg/Header" in defs and "builtin_interfaces/msg/Time" in defs
    assert "float64[] position" in defs["sensor_msgs/msg/JointState"]
    assert "=" * 80 not in defs["sensor_msgs/msg/JointState"]


def chunk_compression(bag: Path) -> set[str]:
    from mcap.reader import make_reader

    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as f:
        return {c.compression for c in make_reader(f).get_summary().chunk_indexes}


def test_bags_are_zstd_compressed_unless_asked_not_to_and_raw_messages_pass_through(tmp_path, contents):
    run = run_of(contents, 5)
    write_run(run, contents.params, tmp_path / "z")
    assert chunk_compression(tmp_path / "z") == {"zstd"}
    with BagWriter(tmp_path / "raw", contents.params, compress=False) as w:
        from rheo_ros.io.messages import JointStateEncoder
        enc = JointStateEncoder(w.types)
        for t, d, v in zip(run.stage_t, run.stage_depth, run.stage_velocity):
            ns = seconds_to_ns(t)
            w.write_raw(STAGE_TOPIC, ns, w.store.serialize_cdr(enc(ns, d, v), TOPIC_TYPES[STAGE_TOPIC]))
    assert chunk_compression(tmp_path / "raw") == {""}
    stage = [(t, v) for s, t, v in bag_samples(tmp_path / "raw") if s == "stage"]
    np.testing.assert_array_equal([t for t, _ in stage], run.stage_t)
    np.testing.assert_array_equal([v for _, v in stage], run.stage_depth)


def test_message_definitions_of_several_types_share_their_dependencies():
    defs = message_definitions(["geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/JointState"])
    assert sorted(defs) == ["builtin_interfaces/msg/Time", "geometry_msgs/msg/Point", "geometry_msgs/msg/Pose",
                            "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/Quaternion",
                            "sensor_msgs/msg/JointState", "std_msgs/msg/Header"]
    assert all("MSG: " not in text for text in defs.values())


def test_bag_repair_rebuilds_a_truncated_recording_and_refuses_what_is_not_one(tmp_path):
    """A recording cut off after its second chunk (no summary, no metadata.yaml): ``repair_bag``
    rebuilds a bag holding every message of the complete chunks, each the original's, with
    the parameters given; a whole bag, an empty folder and a stream with no complete
    message are refused by name."""
    from rheo_ros.io.bag import repair_bag

    source = BAG.parent / "clean_short_keep"   # 2.2 MB: three 1 MiB chunks of zstd-compressed data
    killed = tmp_path / "killed"
    killed.mkdir()
    data = (source / "clean_short_keep.mcap").read_bytes()
    cut = int(0.8 * len(data))
    (killed / "killed.mcap").write_bytes(data[:cut])
    with pytest.raises(BagError, match="has a metadata.yaml: a whole bag, nothing to repair"):
        repair_bag(source)
    counts = repair_bag(killed, read_params(source)).counts
    assert (killed / "metadata.yaml").is_file() and (tmp_path / "killed.mcap.killed").stat().st_size == cut
    whole = {s: [t for k, t, _ in bag_samples(source) if k == s] for s in ("stage", "image", "markers")}
    got = {s: [t for k, t, _ in bag_samples(killed) if k == s] for s in ("stage", "image", "markers")}
    assert 0 < sum(counts.values()) < sum(len(v) for v in whole.values())
    for stream, stamps in got.items():
        assert stamps and set(stamps) <= set(whole[stream]), stream
    assert read_params(killed) == read_params(source)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="0 .mcap files; a recording has one"):
        repair_bag(tmp_path / "empty")
    (tmp_path / "stub").mkdir()
    (tmp_path / "stub" / "stub.mcap").write_bytes(data[:200])
    with pytest.raises(BagError, match="stub.mcap: no complete message in the stream"):
        repair_bag(tmp_path / "stub")


def chunks(bag: Path) -> list:
    """Each chunk record of the bag's MCAP with its byte offset."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    (mcap,) = bag.glob("*.mcap")
    out = []
    with mcap.open("rb") as f:
        records = iter(StreamReader(f, emit_chunks=True).records)
        while True:
            offset = f.tell()
            record = next(records, None)
            if record is None:
                return out
            if isinstance(record, Chunk):
                out.append((offset, record))


def test_every_chunk_carries_its_crc_and_a_corrupt_chunk_is_named_by_its_offset(tmp_path, contents):
    """Issue 21: rosbags' writer leaves each chunk's CRC 0 (unchecked), and 4 kB of random
    bytes over a chunk decoded as garbage. The package's bags carry the CRCs (rewritten
    through mcap's writer, the messages unchanged); the reader checks them and names the
    chunk: its byte offset and its time span. Compressed, the damage breaks the zstd frame;
    uncompressed, one byte changed fails the CRC."""
    run = run_of(contents, 200)
    for name, compress in (("zstd", True), ("raw", False)):
        bag = tmp_path / name
        with BagWriter(bag, contents.params, compress=compress) as w:
            from rheo_ros.io.messages import JointStateEncoder
            enc = JointStateEncoder(w.types)
            for t, d, v in zip(run.stage_t, run.stage_depth, run.stage_velocity):
                w.write(STAGE_TOPIC, seconds_to_ns(t), enc(seconds_to_ns(t), d, v))
        found = chunks(bag)
        assert found and all(c.uncompressed_crc != 0 for _, c in found), name
        stage = [v for s, _, v in bag_samples(bag) if s == "stage"]
        np.testing.assert_array_equal(stage, run.stage_depth)
        (mcap,) = bag.glob("*.mcap")
        data = bytearray(mcap.read_bytes())
        offset, chunk = found[0]
        at = offset + 80   # inside the chunk's data, past its header (the record's 9 bytes, 5 fields)
        if compress:
            data[at:at + 64] = np.random.default_rng(0).bytes(64)
        else:
            data[at + 40] ^= 0x01
        mcap.write_bytes(bytes(data))
        span = f"({chunk.message_start_time * 1e-9:.3f}-{chunk.message_end_time * 1e-9:.3f} s)"
        why = "cannot be decoded" if compress else "fails its CRC: its data were changed on disk"
        with pytest.raises(BagError, match=re.escape(f"{mcap}: the chunk at byte {offset} {span} {why}")):
            list(bag_samples(bag))
