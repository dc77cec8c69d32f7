"""rosbag2 MCAP bags: write a simulated run, read any bag of the contract into a Record.

Layout (contract): a directory with ``metadata.yaml`` and one ``.mcap`` file, CDR,
the three measurement topics; the run's parameters file as YAML text in the
metadata's ``custom_data`` under ``rheo_ros.params``. Chunks are zstd-compressed
inside the MCAP (readable by rosbags and by mcap + mcap-ros2-support).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from struct import error as struct_error
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rheo_ros.config.setup import Setup, params_yaml, parse_params
from rheo_ros.io.errors import BagError
from rheo_ros.io.messages import (
    MARKERS_TOPIC,
    OBJECT_TOPIC,
    OBJECT_TYPE,
    PHASE_TOPIC,
    PHASE_TYPE,
    STAGE_TOPIC,
    TACTILE_TOPIC,
    TOPIC_TYPES,
    JointStateEncoder,
    MarkerArrayEncoder,
    MessageError,
    MessageTypes,
    PressureImageEncoder,
    read_joint_state,
    read_marker_array,
    read_object_hint,
    read_pressure_image,
    read_release_cut,
    stamp_ns,
)
from rheo_ros.record import Record

PARAMS_KEY = "rheo_ros.params"


def typestore() -> Any:
    return get_typestore(Stores.ROS2_KILTED)


class BagWriter:
    """Writes the contract's topics into a new bag directory (``with BagWriter(...) as w``).

    Args:
        path: the bag directory (must not exist).
        params: flat parameters, stored as a parameters file in the metadata.
        topics: topic -> type name; default the three measurement topics.
        definitions: type name -> ``.msg`` text of the types rosbags' store does not know
            (the package's own; ``rheo record`` reads them from the ament index).
    """

    def __init__(self, path: str | Path, params: dict[str, Any] | None = None,
                 topics: dict[str, str] | None = None, compress: bool = True,
                 definitions: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.store = typestore()
        for name, text in (definitions or {}).items():
            self.store.register(get_types_from_msg(text, name))
        self.types = MessageTypes.rosbags(self.store)
        self.writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.compress = compress
        if compress:
            self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        if params is not None:
            self.writer.set_custom_data(PARAMS_KEY, params_yaml(params))
        self._topics = topics or TOPIC_TYPES
        self.connections: dict[str, Any] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        for topic, msgtype in self._topics.items():
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()
        if exc[0] is None:
            with_chunk_crcs(self.path / f"{self.path.name}.mcap")

    def write(self, topic: str, t_ns: int, msg: Any) -> None:
        conn = self.connections[topic]
        self.writer.write(conn, t_ns, self.store.serialize_cdr(msg, conn.msgtype))

    def write_raw(self, topic: str, t_ns: int, data: bytes) -> None:
        self.writer.write(self.connections[topic], t_ns, data)

    def flush(self) -> None:
        """Put what has been written so far on disk as a closed chunk, so that a writer
        killed later loses nothing before this call (``repair_bag`` reads it back).

        rosbags' MCAP writer closes a chunk only at 1 MiB or at ``close``; this reaches
        into its storage (``close_chunk``, the file): rosbags is pinned (requirements.lock)
        and a test kills a recorder to hold this to it."""
        storage = self.writer.storage
        if storage is not None and storage.chunk.bio.tell():
            storage.close_chunk()
        if storage is not None:
            storage.bio.flush()


def with_chunk_crcs(mcap: Path) -> None:
    """Set every chunk's CRC of its data in ``mcap``: rosbags' writer leaves them 0
    (unchecked), and a chunk overwritten on disk then decoded as garbage (``check_chunks``
    names it instead). The CRC is a fixed-size field of the chunk record (after its
    opcode, length and three u64s: the MCAP specification's Chunk), so it is set in
    place: the file keeps its layout, its indexes and the summary's offsets (a rewrite
    through mcap's writer cost as much as writing the bag). The chunks are found by the
    summary's chunk index."""
    import zlib

    import zstandard
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    crc_at = 1 + 8 + 3 * 8   # opcode, record length, start, end, uncompressed size
    patches = []
    with mcap.open("rb") as fh:
        summary = make_reader(fh).get_summary()
        for index in summary.chunk_indexes if summary is not None else ():
            fh.seek(index.chunk_start_offset)
            records = StreamReader(BytesIO(fh.read(index.chunk_length)), skip_magic=True, emit_chunks=True).records
            chunk = next(iter(records))
            if isinstance(chunk, Chunk) and chunk.uncompressed_crc == 0:
                data = (zstandard.decompress(chunk.data, chunk.uncompressed_size)
                        if chunk.compression == "zstd" else chunk.data)
                patches.append((index.chunk_start_offset, zlib.crc32(data)))
    with mcap.open("r+b") as fh:
        for offset, crc in patches:
            fh.seek(offset)
            if fh.read(1) != b"\x06":   # the summary's offset is the record's start
                raise BagError(f"{mcap}: no chunk record at byte {offset}: cannot set its CRC")
            fh.seek(offset + crc_at)
            fh.write(crc.to_bytes(4, "little"))


def check_chunks(mcap: Path) -> None:
    """Every chunk of ``mcap`` decompresses and matches its CRC (where it has one).

    Raises:
        BagError: names the file, the chunk's byte offset and its time span."""
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import CRCValidationError, StreamReader, get_chunk_data_stream

    repair = f"; `rheo bag repair {mcap.parent}` rebuilds the bag from the chunks that read"
    with mcap.open("rb") as fh:
        records = iter(StreamReader(fh, emit_chunks=True).records)
        while True:
            offset = fh.tell()
            try:
                record = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, ValueError, struct_error):
                return   # a damaged structure: rosbags' reader names it (bag_reader)
            if not isinstance(record, Chunk):
                continue
            where = (f"{mcap}: the chunk at byte {offset} ({record.message_start_time * 1e-9:.3f}-"
                     f"{record.message_end_time * 1e-9:.3f} s)")
            try:
                get_chunk_data_stream(record, validate_crc=True)   # decompressed and checked, not parsed
            except CRCValidationError:
                raise BagError(f"{where} fails its CRC: its data were changed on disk{repair}") from None
            except Exception as exc:   # zstandard's own errors
                raise BagError(f"{where} cannot be decoded ({type(exc).__name__}: {exc}): corrupt{repair}") from None


def require_bag(path: str | Path) -> Path:
    """``path`` as a Path, if it is a rosbag2 directory (it has a metadata.yaml).

    Raises:
        BagError: it is not; where it holds an .mcap file (a recording whose writer was
            killed), the message says to repair it (``repair_bag``)."""
    path = Path(path)
    meta = path / "metadata.yaml"
    if meta.exists() and not meta.is_file():   # not a killed recording: no repair hint
        raise BagError(f"{meta}: is a {'directory' if meta.is_dir() else 'special file'}, not a file: a rosbag2 "
                       "directory's metadata.yaml is a YAML file")
    if not meta.is_file():
        hint = ("; it holds an .mcap file: a recording whose writer was killed? `rheo bag repair "
                f"{path}` rebuilds it") if path.is_dir() and any(path.glob("*.mcap")) else ""
        raise BagError(f"{path}: not a rosbag2 directory (no metadata.yaml){hint}")
    return path


RECORDING_PARAMS = "recording.params.yaml"   # in a bag being recorded: its parameters until metadata.yaml


@dataclass(frozen=True)
class Repaired:
    """What ``repair_bag`` rebuilt.

    Attributes:
        counts: the messages in the rebuilt bag, per topic.
        kept: where the original files went (beside the bag, never deleted).
        lost: a whole bag's messages in chunks that did not read, per topic (empty for a
            killed recording: its lost tail was never counted).
        spans: the log-time spans (s) of the chunks that did not read.
    """

    counts: dict[str, int]
    kept: tuple[Path, ...]
    lost: dict[str, int] = field(default_factory=dict)
    spans: tuple[tuple[float, float], ...] = ()


def repair_bag(path: str | Path, params: dict[str, Any] | None = None) -> Repaired:
    """Rebuild a bag from what of its MCAP reads, the original kept beside it.

    A recording whose writer was killed (an ``.mcap`` with no summary, no
    ``metadata.yaml``): every complete message of the stream; the unreadable tail (a chunk
    cut short) is dropped, the file kept as ``NAME.mcap.killed``. A whole bag one of whose
    chunks fails its CRC or does not decompress (``check_chunks``): every message of the
    chunks that read, the file and its metadata kept as ``NAME.mcap.damaged`` and
    ``NAME.metadata.yaml.damaged``; what was lost is counted from the MCAP's summary.
    Parameters: ``params``, else the bag's own (a whole bag) or the recorder's
    ``recording.params.yaml``.

    Raises:
        BagError: nothing to repair (a whole bag whose chunks all read), no or several
            .mcap files, nothing readable, a file in the way of the ones kept.
    """
    path = Path(path)
    whole = (path / "metadata.yaml").is_file()
    if (path / "metadata.yaml").exists() and not whole:
        require_bag(path)   # a metadata.yaml that is no file: said so
    mcaps = sorted(path.glob("*.mcap"))
    if len(mcaps) != 1:
        raise BagError(f"{path}: {len(mcaps)} .mcap files; a recording has one" if not whole else
                       f"{path}: {len(mcaps)} .mcap files; rheo bag repair rebuilds a bag of one")
    stream = _readable_records(mcaps[0])
    if whole and not stream.spans:
        raise BagError(f"{path}: has a metadata.yaml: a whole bag, nothing to repair (every chunk reads)")
    if not stream.messages:
        raise BagError(f"{mcaps[0]}: no complete message in the stream ({stream.lost or 'empty'})")
    custom: dict[str, str] = {}
    params_file = path / RECORDING_PARAMS
    if whole:
        custom = _custom_data(path)   # the recorded parameters' own text among them
        if params is None:
            read_params(path)   # checked, and kept as written (with effects this installation may lack)
    elif params is None and params_file.is_file():
        text = params_file.read_text()
        parse_params(text, str(params_file), recorded=True)
        custom[PARAMS_KEY] = text
    if params is not None:
        custom[PARAMS_KEY] = params_yaml(params)
    suffix = ".damaged" if whole else ".killed"
    kept = [(mcaps[0], path.with_name(mcaps[0].name + suffix))]
    if whole:
        kept.append((path / "metadata.yaml", path.with_name(f"{path.name}.metadata.yaml{suffix}")))
    for _, there in kept:
        if there.exists():
            raise BagError(f"{there}: exists (an earlier repair?); move it away first: the original goes there")
    others = sorted(p.name for p in path.iterdir() if p not in {here for here, _ in kept} | {params_file})
    if others:   # the folder is replaced by the rebuilt bag: nothing else may be in it
        raise BagError(f"{path}: holds {', '.join(others)} besides the bag's files; move it out first")
    rebuilt = path.with_name(path.name + ".repairing")
    if rebuilt.exists():
        raise BagError(f"{rebuilt}: exists (an earlier repair stopped?); remove it first")
    counts = _write_rebuilt(rebuilt, stream, custom)
    # The original files go beside the bag (kept: nothing is thrown away), the rebuilt bag in its place.
    for here, there in kept:
        here.rename(there)
    (rebuilt / f"{rebuilt.name}.mcap").rename(rebuilt / f"{path.name}.mcap")
    meta = (rebuilt / "metadata.yaml").read_text().replace(f"{rebuilt.name}.mcap", f"{path.name}.mcap")
    (rebuilt / "metadata.yaml").write_text(meta)
    if params_file.is_file():
        params_file.unlink()
    path.rmdir()   # empty now: anything else in it stops the repair here, before any loss
    rebuilt.rename(path)
    topic_of = {cid: c.topic for cid, c in stream.channels.items()}
    lost: dict[str, int] = {}
    for cid, total in stream.totals.items():
        if cid in topic_of:
            lost[topic_of[cid]] = lost.get(topic_of[cid], 0) + total - stream.read_per_channel.get(cid, 0)
    return Repaired(counts, tuple(there for _, there in kept), lost if whole else {}, tuple(stream.spans))


@dataclass
class _Readable:
    """What of an MCAP file reads: its schemas, channels and messages; the log-time spans
    (s) of the chunks that do not read; why the stream ended early ("": it did not); the
    messages per channel its summary counts (``Statistics``; empty without one)."""

    schemas: dict[int, Any] = field(default_factory=dict)
    channels: dict[int, Any] = field(default_factory=dict)
    messages: list[Any] = field(default_factory=list)
    spans: list[tuple[float, float]] = field(default_factory=list)
    lost: str = ""
    totals: dict[int, int] = field(default_factory=dict)
    read_per_channel: dict[int, int] = field(default_factory=dict)


def _readable_records(mcap: Path) -> _Readable:
    """Every record of ``mcap`` that reads, chunk by chunk (mcap's StreamReader and
    ``breakup_chunk``): a chunk that fails its CRC or does not decompress is skipped
    whole, its span noted; a damaged structure ends the stream there."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Chunk, Message, Schema, Statistics
    from mcap.stream_reader import StreamReader, breakup_chunk

    out = _Readable()
    with mcap.open("rb") as fh:
        try:
            for record in StreamReader(fh, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    try:
                        inner = breakup_chunk(record, validate_crc=True)
                    except Exception:   # a CRC mismatch, zstandard's or the parser's errors: the chunk is lost
                        out.spans.append((record.message_start_time * 1e-9, record.message_end_time * 1e-9))
                        continue
                else:
                    inner = [record]
                for r in inner:
                    if isinstance(r, Schema):
                        out.schemas[r.id] = r
                    elif isinstance(r, Channel):
                        out.channels[r.id] = r
                    elif isinstance(r, Message):
                        out.messages.append(r)
                        out.read_per_channel[r.channel_id] = out.read_per_channel.get(r.channel_id, 0) + 1
                    elif isinstance(r, Statistics):
                        out.totals = dict(r.channel_message_counts)
        except (McapError, EOFError, ValueError, struct_error) as exc:
            out.lost = f"{type(exc).__name__}: {exc}"   # the tail the writer never finished
    return out


def _custom_data(path: Path) -> dict[str, str]:
    """The text entries of a bag's metadata custom_data (carried into a rebuilt bag)."""
    info = yaml.safe_load((path / "metadata.yaml").read_text()) or {}
    custom = (info.get("rosbag2_bagfile_information") or {}).get("custom_data") or {}
    return {k: v for k, v in custom.items() if isinstance(k, str) and isinstance(v, str)}


def _write_rebuilt(rebuilt: Path, stream: _Readable, custom: dict[str, str]) -> dict[str, int]:
    """A new bag at ``rebuilt`` of ``stream``'s messages in log-time order; counts per topic."""
    store = get_typestore(Stores.EMPTY)
    for schema in stream.schemas.values():
        store.register(get_types_from_msg(schema.data.decode(), schema.name))
    topics = {c.topic: stream.schemas[c.schema_id].name for c in stream.channels.values()}
    counts = dict.fromkeys(topics, 0)
    writer = Writer(rebuilt, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in custom.items():
        writer.set_custom_data(key, value)
    with writer:
        conns = {cid: writer.add_connection(c.topic, topics[c.topic], typestore=store)
                 for cid, c in stream.channels.items()}
        for m in sorted(stream.messages, key=lambda m: (m.log_time, m.sequence)):
            writer.write(conns[m.channel_id], m.log_time, m.data)
            counts[stream.channels[m.channel_id].topic] += 1
    with_chunk_crcs(rebuilt / f"{rebuilt.name}.mcap")
    return counts


def seconds_to_ns(t: float) -> int:
    return int(round(t * 1e9))


@dataclass(frozen=True)
class BagContents:
    """What a bag holds, decoded: the record, the parameters, and the raw frames."""

    record: Record
    params: dict[str, Any]
    tactile_t: np.ndarray
    tactile: np.ndarray   # (T, rows, cols) Pa
    stage_velocity: np.ndarray


def read_params(path: str | Path) -> dict[str, Any] | None:
    """The parameters stored in a bag's metadata, or None when it holds none.

    Raises:
        BagError: metadata.yaml unreadable or not rosbag2 metadata.
    """
    meta = Path(path) / "metadata.yaml"
    try:
        info = yaml.safe_load(meta.read_text())
    except OSError as exc:
        raise BagError(f"{meta}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise BagError(f"{meta}: not text (byte {exc.start} is not UTF-8)") from None
    except yaml.YAMLError as exc:
        raise BagError(f"{meta}: not YAML: {str(exc).splitlines()[0]}") from None
    info = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{meta}: no rosbag2_bagfile_information mapping")
    custom = info.get("custom_data") or {}
    if not isinstance(custom, dict):
        raise BagError(f"{meta}: custom_data is not a mapping")
    text = custom.get(PARAMS_KEY)
    if text and not isinstance(text, str):
        raise BagError(f"{meta}: custom_data {PARAMS_KEY}: {str(text)[:40]!r} ({type(text).__name__}) is not a "
                       "parameters file's text")
    return parse_params(text, f"{meta}: custom_data {PARAMS_KEY}", recorded=True) if text else None


@contextmanager
def bag_reader(path: Path, chunks_checked: bool = False) -> Iterator[AnyReader]:
    """rosbags' reader on a bag directory, its chunks checked first (``check_chunks``)
    unless ``chunks_checked`` (this pass's caller read the bag through a checked reader
    already); what a damaged bag raises inside (rosbags raises several types: bad metadata
    bytes, truncated chunks) as a BagError naming it."""
    for mcap in sorted(path.glob("*.mcap")) if not chunks_checked else ():
        check_chunks(mcap)
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            yield reader
    except BagError:
        raise
    except Exception as exc:
        why = next(filter(None, map(mcap_damage, sorted(path.glob("*.mcap")))), " ".join(str(exc).split()))
        raise BagError(f"{path}: cannot read bag: {why}") from None


MCAP_MAGIC = b"\x89MCAP0\r\n"


def mcap_damage(mcap: Path) -> str | None:
    """What is wrong with the ends of ``mcap`` in words (rosbags says "File end magic is
    invalid"), or None when both ends are an MCAP file's."""
    size = mcap.stat().st_size
    with mcap.open("rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
        fh.seek(max(size - len(MCAP_MAGIC), 0))
        tail = fh.read()
    if size == 0:
        return f"{mcap.name} is empty (0 bytes)"
    if head != MCAP_MAGIC:
        return f"{mcap.name} is not an MCAP file (it does not start with the MCAP magic)"
    if tail != MCAP_MAGIC or size < 2 * len(MCAP_MAGIC):
        return (f"{mcap.name} ends at byte {size} without the MCAP footer: cut short (copied in part, or its "
                "writer was killed)")
    return None


def _messages(path: Path, topics: Iterable[str], chunks_checked: bool = False) -> Iterator[tuple[str, Any]]:
    with bag_reader(path, chunks_checked) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        expected = {**TOPIC_TYPES, OBJECT_TOPIC: OBJECT_TYPE, PHASE_TOPIC: PHASE_TYPE}
        for c in conns:
            if c.topic in expected and c.msgtype != expected[c.topic]:
                raise BagError(f"{path}: {c.topic}: a connection of type {c.msgtype}; the contract's is "
                               f"{expected[c.topic]}")
        if not conns:
            return   # rosbags reads every connection when given none
        for conn, t, raw in reader.messages(connections=conns):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:   # rosbags raises several types on bytes that are not CDR of the type
                raise BagError(f"{path}: {conn.topic}: the message logged at {t * 1e-9:.3f} s is not a "
                               f"{conn.msgtype} ({' '.join(str(exc).split())})") from None
            yield conn.topic, msg


def read_bag(path: str | Path, params: dict[str, Any] | None = None) -> BagContents:
    """Decode a bag of the contract into a ``Record`` (header stamps, nodal forces).

    Args:
        path: bag directory.
        params: flat parameters overriding the bag's own (``--params-file``).

    Raises:
        BagError: unreadable bag, missing topic, malformed message (the message
            names the file, topic and field).
    """
    path = require_bag(path)
    params = params or read_params(path)
    if params is None:
        raise BagError(f"{path}: no parameters in the bag's metadata; give --params-file")
    setup = Setup(params)
    data: dict[str, list] = {STAGE_TOPIC: [], TACTILE_TOPIC: [], MARKERS_TOPIC: []}
    decode = {STAGE_TOPIC: read_joint_state, TACTILE_TOPIC: read_pressure_image, MARKERS_TOPIC: read_marker_array}
    for topic, msg in _messages(path, data):
        try:
            data[topic].append((stamp_ns(msg), decode[topic](msg)))
        except MessageError as exc:
            raise BagError(f"{path}: {topic}: {exc}") from None
    for topic, rows in data.items():
        if not rows:
            raise BagError(f"{path}: {topic}: no messages")
        rows.sort(key=lambda r: r[0])
    stage_t = np.array([r[0] for r in data[STAGE_TOPIC]]) * 1e-9
    stage = np.array([r[1] for r in data[STAGE_TOPIC]])
    tactile_t = np.array([r[0] for r in data[TACTILE_TOPIC]]) * 1e-9
    images = np.array([r[1] for r in data[TACTILE_TOPIC]])
    marker_t = np.array([r[0] for r in data[MARKERS_TOPIC]]) * 1e-9
    markers = np.array([r[1] for r in data[MARKERS_TOPIC]])
    mesh, tactile = setup.mesh, setup.tactile
    if images.shape[1:] != (tactile.rows, tactile.cols):
        raise BagError(f"{path}: {TACTILE_TOPIC}: images {images.shape[1:]}, parameters say "
                          f"{tactile.rows} x {tactile.cols}")
    if markers.shape[1:] != mesh.nodes.shape:
        raise BagError(f"{path}: {MARKERS_TOPIC}: {markers.shape[1]} markers, parameters say {mesh.nodes.shape[0]}")
    record = setup.record(stage_t, stage[:, 0], tactile_t, images, marker_t, markers, str(path))
    return BagContents(record, params, tactile_t, images, stage[:, 1])


def bag_samples(path: str | Path) -> Iterator[tuple[str, float, Any]]:
    """The measurement samples of a bag in recorded order, as the online estimator
    takes them: ``("stage", t, depth)``, ``("image", t, pressures)``, ``("markers", t, xy)``
    and, where the bag holds ``/rheo/object``, ``("object", t, hint)``, with ``t`` the
    header stamp (s).

    Raises:
        BagError: unreadable bag or malformed message (names the topic and field).
    """
    path = Path(path)
    decode = {STAGE_TOPIC: ("stage", lambda m: read_joint_state(m)[0]), TACTILE_TOPIC: ("image", read_pressure_image),
              MARKERS_TOPIC: ("markers", read_marker_array), OBJECT_TOPIC: ("object", read_object_hint)}
    for topic, msg in _messages(path, decode):
        stream, read = decode[topic]
        try:
            yield stream, stamp_ns(msg) * 1e-9, read(msg)
        except MessageError as exc:
            raise BagError(f"{path}: {topic}: {exc}") from None


def release_cuts(path: str | Path, chunks_checked: bool = False) -> list[tuple[float, float, str]]:
    """The releases a node closed before they settled, as the recording's ``/rheo/phase``
    says (``read_release_cut``: the latest sample the node had, the release's end, s,
    and why), in time order; none where the bag did not record that topic. ``rheo analyze`` closes those releases there too: a node
    that heard nothing for ``estimator.stale_after`` s of its wall clock fitted what it
    had, while a recording may go on at later stamps (a simulator that stalled).
    ``chunks_checked``: as ``bag_reader``'s.

    Raises:
        BagError: unreadable bag or a /rheo/phase message that does not decode.
    """
    cuts = []
    for _, msg in _messages(Path(path), (PHASE_TOPIC,), chunks_checked):
        try:
            cut = read_release_cut(msg)
        except AttributeError as exc:
            raise BagError(f"{path}: {PHASE_TOPIC}: {exc}") from None
        if cut is not None:
            cuts.append(cut)
    return sorted(cuts)


def write_run(run: Any, params: dict[str, Any], out: str | Path) -> dict[str, int]:
    """Write a simulated ``Run`` as a bag, messages in stamp order; counts per topic."""
    series = [(STAGE_TOPIC, run.stage_t), (TACTILE_TOPIC, run.tactile_t), (MARKERS_TOPIC, run.marker_t)]
    stamps = np.concatenate([np.round(t * 1e9).astype(np.int64) for _, t in series])
    which = np.concatenate([np.full(t.size, k) for k, (_, t) in enumerate(series)])
    index = np.concatenate([np.arange(t.size) for _, t in series])
    order = np.lexsort((which, stamps))
    depth, velocity = run.stage_depth.tolist(), run.stage_velocity.tolist()
    with BagWriter(out, params) as bag:
        stage, tactile, markers = (JointStateEncoder(bag.types), PressureImageEncoder(bag.types),
                                   MarkerArrayEncoder(bag.types))
        conns = [bag.connections[topic] for topic, _ in series]
        serialize, write = bag.store.serialize_cdr, bag.writer.write
        for ns, k, i in zip(stamps[order].tolist(), which[order].tolist(), index[order].tolist()):
            if k == 0:
                msg = stage(ns, depth[i], velocity[i])
            elif k == 1:
                msg = tactile(ns, run.tactile[i])
            else:
                msg = markers(ns, run.markers[i])
            write(conns[k], ns, serialize(msg, conns[k].msgtype))
    return {topic: t.size for topic, t in series}


def message_definitions(typenames: Iterable[str]) -> dict[str, str]:
    """``.msg`` text of each type and of every type it uses (rosbags' typestore)."""
    store, out = typestore(), {}
    todo = list(typenames)
    while todo:
        name = todo.pop()
        if name in out:
            continue
        text, _ = store.generate_msgdef(name, ros_version=2)
        sections = text.split("=" * 80 + "\n")
        out[name] = sections[0]
        used = (s.split("\n", 1)[0].removeprefix("MSG: ") for s in sections[1:])
        todo += [u if "/msg/" in u else u.replace("/", "/msg/", 1) for u in used]
    return out
