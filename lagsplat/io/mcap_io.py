"""Read camera frames and numeric actuation logs from an MCAP file.

Supported message encodings:

* ``json`` (what ``foxglove`` tools and :mod:`mcap.writer` users write):
    - image topic: ``foxglove.CompressedImage``-style objects
      ``{"timestamp": {"sec", "nsec"} (optional), "format": "png" | "jpeg",
      "data": <base64 string>}`` (a list of byte values is accepted too);
    - actuation topics: every numeric field of each object is a channel.
      Nested objects are flattened with ``.`` (``{"a": {"b": 1}}`` ->
      ``a.b``), numeric lists with ``[i]`` (``p[0]``); booleans, strings and
      the top-level ``timestamp`` / ``header`` fields (times, not data) are
      skipped; ``null`` counts as NaN.
* ``cdr`` (ROS 2), minimal: ``sensor_msgs/msg/CompressedImage`` on the image
  topic and ``std_msgs/msg/Float64`` / ``Float32`` (field ``data``) on
  actuation topics. Other ROS 2 message types are refused with a ClipError.

Times: a frame's time is its message's ``log_time`` (ns), converted to
seconds and shifted to start at 0; then the timing rule of
:mod:`lagsplat.io.timing` applies, with no container frame rate: if ``fps``
is given the frames get uniform times ``i / fps`` (warning if the log times
jitter or their mean rate differs by > 1 %); regular log times are used as
they are; jittering log times without ``fps`` are an error.

Channel names: a field is named by the field alone if no other actuation
topic has a field of the same name, else ``"<topic>/<field>"`` (e.g. two
ROS topics ``/p1`` and ``/p2`` with a ``data`` field give ``/p1/data`` and
``/p2/data``; one topic ``/pressure`` with fields ``p1, p2`` gives ``p1,
p2``). Channels are ordered by topic (as listed) then by first appearance.

Alignment: each channel is sampled onto the frames' log times by zero-order
hold: a frame takes the channel's last sample logged at or before it; frames
logged before the channel's first sample take that first sample. Alignment
always uses the real log times, also when ``fps`` replaces the frame times.
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from pathlib import Path
from typing import Any, Iterator, Sequence

import cv2
import numpy as np

from lagsplat.io.common import FrameCollector, FrameTransform, check_range, cv_to_rgb, validate_range
from lagsplat.io.clip import ClipError
from lagsplat.io.timing import resolve_timing

__all__ = ["read_mcap", "zero_order_hold"]

_SKIP_TOP = ("timestamp", "header")
_ROS_IMAGE = "sensor_msgs/msg/CompressedImage"
_ROS_SCALARS = {"std_msgs/msg/Float64": ("d", 8), "std_msgs/msg/Float32": ("f", 4)}


def zero_order_hold(sample_t: np.ndarray, values: np.ndarray, query_t: np.ndarray) -> np.ndarray:
    """Sample a step signal at ``query_t`` (zero-order hold).

    Args:
        sample_t: ``[N]`` non-decreasing sample times (any unit, N >= 1).
        values: ``[N]`` sample values.
        query_t: ``[T]`` query times, same unit.

    Returns:
        ``[T]``: for each query the value of the last sample at or before it;
        queries before the first sample get the first value.
    """
    idx = np.searchsorted(np.asarray(sample_t), np.asarray(query_t), side="right") - 1
    return np.asarray(values)[np.clip(idx, 0, None)]


# ---------------------------------------------------------------- decoding
class _Cdr:
    """Minimal little/big-endian CDR reader (offsets relative to payload)."""

    def __init__(self, data: bytes) -> None:
        if len(data) < 4:
            raise ValueError("CDR message shorter than its header")
        self.le = data[1] & 1 == 1
        self.buf = memoryview(data)[4:]
        self.pos = 0

    def _align(self, n: int) -> None:
        self.pos += (-self.pos) % n

    def _unpack(self, fmt: str, size: int) -> Any:
        self._align(size)
        if self.pos + size > len(self.buf):
            raise ValueError("CDR message ends early")
        v = struct.unpack_from(("<" if self.le else ">") + fmt, self.buf, self.pos)[0]
        self.pos += size
        return v

    def uint32(self) -> int:
        return self._unpack("I", 4)

    def scalar(self, fmt: str, size: int) -> float:
        return self._unpack(fmt, size)

    def octets(self) -> bytes:
        n = self.uint32()
        if self.pos + n > len(self.buf):
            raise ValueError("CDR sequence ends early")
        out = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return out

    def string(self) -> str:
        return self.octets().rstrip(b"\x00").decode("utf-8", errors="replace")


def _image_bytes(src: str, topic: str, k: int, schema_name: str, encoding: str, data: bytes) -> tuple[bytes, str]:
    try:
        if encoding == "json":
            obj = json.loads(data)
            if not isinstance(obj, dict) or "data" not in obj:
                raise ValueError("no 'data' field")
            d = obj["data"]
            raw = base64.b64decode(d, validate=True) if isinstance(d, str) else bytes(d)
            return raw, str(obj.get("format", ""))
        if encoding == "cdr" and schema_name == _ROS_IMAGE:
            r = _Cdr(data)
            r.uint32(), r.uint32()  # header.stamp sec, nanosec
            r.string()  # header.frame_id
            fmt = r.string()
            return r.octets(), fmt
    except (ValueError, TypeError, binascii.Error, UnicodeDecodeError) as exc:
        raise ClipError(f"{src}: image message {k} on '{topic}' cannot be parsed ({exc})") from exc
    raise ClipError(
        f"{src}: image topic '{topic}' uses encoding '{encoding}' / schema '{schema_name}'; "
        f"supported are JSON CompressedImage and ROS 2 {_ROS_IMAGE}"
    )


def _flatten(obj: Any, prefix: str, out: dict[str, float]) -> None:
    if isinstance(obj, bool) or isinstance(obj, str):
        return
    if obj is None:
        out[prefix] = float("nan")
    elif isinstance(obj, (int, float)):
        out[prefix] = float(obj)
    elif isinstance(obj, dict):
        for k, v in obj.items():
            if not prefix and k in _SKIP_TOP:
                continue
            _flatten(v, f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _flatten(v, f"{prefix}[{i}]", out)


def _numeric_fields(src: str, topic: str, k: int, schema_name: str, encoding: str, data: bytes) -> dict[str, float]:
    try:
        if encoding == "json":
            out: dict[str, float] = {}
            _flatten(json.loads(data), "", out)
            return out
        if encoding == "cdr" and schema_name in _ROS_SCALARS:
            fmt, size = _ROS_SCALARS[schema_name]
            return {"data": float(_Cdr(data).scalar(fmt, size))}
    except (ValueError, TypeError, UnicodeDecodeError) as exc:
        raise ClipError(f"{src}: message {k} on '{topic}' cannot be parsed ({exc})") from exc
    raise ClipError(
        f"{src}: actuation topic '{topic}' uses encoding '{encoding}' / schema '{schema_name}'; "
        f"supported are JSON objects and ROS 2 {', '.join(_ROS_SCALARS)}"
    )


# ---------------------------------------------------------------- reading
def _iter_messages(src: str, fh: Any, topics: list[str]) -> tuple[list[str], Iterator[tuple[Any, Any, Any]]]:
    """Return (available topics, iterator over messages of ``topics``)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        reader = make_reader(fh)
        summary = reader.get_summary()
    except (McapError, struct.error, ValueError, EOFError) as exc:
        raise ClipError(f"{src}: cannot read MCAP, the file is truncated or corrupt ({type(exc).__name__}: {exc})") from exc
    if summary is not None:
        available = sorted({ch.topic for ch in summary.channels.values()})
    else:  # no summary section: one pass to list the topics
        try:
            available = sorted({ch.topic for _, ch, _ in reader.iter_messages()})
        except (McapError, struct.error, ValueError, EOFError) as exc:
            raise ClipError(f"{src}: cannot read MCAP, the file is truncated or corrupt ({type(exc).__name__}: {exc})") from exc
    missing = [t for t in topics if t not in available]
    if missing:
        raise ClipError(f"{src}: no topic {', '.join(repr(t) for t in missing)} (topics found: {', '.join(available) or 'none'})")

    def gen() -> Iterator[tuple[Any, Any, Any]]:
        try:
            yield from reader.iter_messages(topics=topics, log_time_order=True)
        except (McapError, struct.error, ValueError, EOFError) as exc:
            raise ClipError(f"{src}: cannot read MCAP, the file is truncated or corrupt ({type(exc).__name__}: {exc})") from exc

    return available, gen()


def read_mcap(
    path: str | Path,
    image_topic: str,
    actuation_topics: Sequence[str] | None = None,
    fps: float | None = None,
    *,
    max_fps: float = 240.0,
    jitter_tol: float = 0.05,
    start: int = 0,
    stop: int | None = None,
    transform: FrameTransform | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], dict[str, Any]]:
    """Read frames from ``image_topic`` and actuation from ``actuation_topics``.

    Args:
        path: the ``.mcap`` file.
        image_topic: topic carrying compressed images (see module docstring).
        actuation_topics: topics with numeric messages; None or ``[]``: no
            actuation.
        fps: true capture rate in Hz or None (timing rule).
        max_fps, jitter_tol: see :func:`lagsplat.io.timing.resolve_timing`.
        start, stop: keep only frames ``[start, stop)``; only those are decoded.
        transform: optional per-frame function (uint8 ``[H, W, 3]`` -> uint8
            ``[h, w, 3]``).

    Returns:
        ``(frames, t, u, u_names, info)``: frames uint8 ``[T, h, w, 3]`` RGB;
        ``t`` float64 ``[T]`` seconds with ``t[0] = 0``; ``u`` float32
        ``[T, n_u]`` zero-order-held onto the frames; ``u_names`` channel
        names; ``info`` with the timing fields of
        :func:`~lagsplat.io.timing.resolve_timing` plus ``image_topic``,
        ``image_format``, ``n_messages``, ``channels`` (per channel: topic,
        field, sample count), native ``width`` / ``height``, ``frames``,
        ``topics`` (all topics of the file).

    Raises:
        ClipError: missing file; unreadable / truncated MCAP; a topic not in
            the file (the message lists the available topics); no image
            message; an undecodable image or message; unsupported encoding;
            an actuation topic without messages or numeric fields; NaN / inf
            in a channel (named); the timing rule's error.

    Warns:
        TimingWarning: see :mod:`lagsplat.io.timing`.
    """
    path = Path(path)
    src = str(path)
    start, stop = validate_range(src, start, stop)
    if not path.exists():
        raise ClipError(f"{src}: file not found")
    if path.is_dir():
        raise ClipError(f"{src}: is a folder, not an .mcap file")
    act_topics = [str(a) for a in (actuation_topics or [])]
    if image_topic in act_topics:
        raise ClipError(f"{src}: '{image_topic}' is both the image topic and an actuation topic")

    collector = FrameCollector(src, start, stop, transform)
    frame_ns: list[int] = []
    formats: set[str] = set()
    samples: dict[str, dict[str, tuple[list[int], list[float]]]] = {a: {} for a in act_topics}
    counts: dict[str, int] = {a: 0 for a in act_topics}
    with open(path, "rb") as fh:
        available, messages = _iter_messages(src, fh, [image_topic, *act_topics])
        for schema, channel, msg in messages:
            sname = schema.name if schema is not None else ""
            enc = channel.message_encoding
            if channel.topic == image_topic:
                k = len(frame_ns)
                frame_ns.append(int(msg.log_time))
                if collector.wants(k):
                    raw, fmt = _image_bytes(src, image_topic, k, sname, enc, msg.data)
                    formats.add(fmt)
                    img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED) if raw else None
                    if img is None:
                        raise ClipError(f"{src}: image message {k} on '{image_topic}' cannot be decoded (format '{fmt}')")
                    collector.add(k, cv_to_rgb(img, src))
            else:
                topic = channel.topic
                k = counts[topic]
                counts[topic] = k + 1
                for field, v in _numeric_fields(src, topic, k, sname, enc, msg.data).items():
                    ts, vs = samples[topic].setdefault(field, ([], []))
                    ts.append(int(msg.log_time))
                    vs.append(v)

    n = len(frame_ns)
    if n == 0:
        raise ClipError(f"{src}: image topic '{image_topic}' has no messages")
    start, stop_ = check_range(src, start, stop, n)
    frame_ns_arr = np.asarray(frame_ns, dtype=np.int64)
    t_all, info = resolve_timing(
        (frame_ns_arr - frame_ns_arr[0]) / 1e9, src, fps=fps, container_fps=None, has_container=False,
        max_fps=max_fps, jitter_tol=jitter_tol,
    )
    frames = collector.result()

    # actuation channels
    field_topics: dict[str, int] = {}
    for topic in act_topics:
        if counts[topic] == 0:
            raise ClipError(f"{src}: actuation topic '{topic}' has no messages")
        if not samples[topic]:
            raise ClipError(f"{src}: actuation topic '{topic}' has no numeric fields")
        for field in samples[topic]:
            field_topics[field] = field_topics.get(field, 0) + 1
    names: list[str] = []
    cols: list[np.ndarray] = []
    chan_info: list[dict[str, Any]] = []
    sel_ns = frame_ns_arr[start:stop_]
    for topic in act_topics:
        for field, (ts, vs) in samples[topic].items():
            name = field if field_topics[field] == 1 else f"{topic}/{field}"
            v = np.asarray(vs, dtype=np.float64)
            bad = ~np.isfinite(v.astype(np.float32))
            if bad.any():
                raise ClipError(f"{src}: actuation channel '{name}' contains NaN or inf ({int(bad.sum())} of {v.size} samples)")
            order = np.argsort(np.asarray(ts, dtype=np.int64), kind="stable")
            ts_arr = np.asarray(ts, dtype=np.int64)[order]
            cols.append(zero_order_hold(ts_arr, v[order], sel_ns).astype(np.float32))
            names.append(name)
            chan_info.append({"name": name, "topic": topic, "field": field, "n_samples": int(v.size)})
    T = stop_ - start
    u = np.stack(cols, axis=1) if cols else np.zeros((T, 0), np.float32)
    assert collector.native_shape is not None
    info.update(
        {
            "reader": "mcap",
            "image_topic": image_topic,
            "image_format": sorted(formats),
            "n_messages": n,
            "channels": chan_info,
            "topics": available,
            "width": collector.native_shape[1],
            "height": collector.native_shape[0],
            "frames": [start, stop_],
            "t_start_s": float(t_all[start]),
            "log_time_start_ns": int(frame_ns_arr[start]),
        }
    )
    t = t_all[start:stop_] - t_all[start]
    return frames, t, np.ascontiguousarray(u, dtype=np.float32), names, info
