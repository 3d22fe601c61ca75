"""The detector's onnxruntime session: session options, the SSD graph without its in-graph NMS, and a cache.

TensorFlow Object Detection exports (the shipped SSD-MobileNetV2) end in a per-class non-maximum suppression
that tf2onnx turns into a loop of about 7,000 small nodes over the 90 classes. Running them costs about as much
as a quarter of the network and optimising them at load time about 18 s. `prepare_session` can cut the graph at
the decoded boxes and sigmoid scores (`SSD_HEAD_OUTPUTS`) so that the detector does the suppression in numpy
(`detector.postprocess_ssd_head`), which gives the same detections.

Prepared graphs (cut, optionally INT8-quantised, and optimised by onnxruntime at the portable `extended` level)
are saved once per user in a cache folder, keyed by the model's sha256, the onnxruntime version, the execution
provider and the variant, written atomically (a temporary sibling renamed into place), so the next start-up only
loads them.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import ConfigError

# Decoded boxes (1, A, 4) normalised (ymin, xmin, ymax, xmax) and sigmoid scores (1, A, 1 + C) with the
# background in column 0, as named by tf2onnx in TF-OD SSD exports.
SSD_HEAD_OUTPUTS: tuple[str, str] = ("Postprocessor/Reshape_2:0", "Postprocessor/convert_scores:0")

GRAPH_OPTIMIZATIONS = ("disable", "basic", "extended", "all")
NMS_MODES = ("auto", "graph", "numpy")


@dataclass(frozen=True)
class SessionSettings:
    """How to build the session (the onnxruntime part of `DetectorConfig`).

    - `nms`: "graph" runs the model as exported; "numpy" cuts a TF-OD SSD graph before its NMS (error when the
      model has no such tensors); "auto" cuts it when it can.
    - `cache_dir`: folder for prepared graphs; None = no cache (prepared in memory at every start).
    """

    intra_op_threads: int = 2
    graph_optimization: str = "all"
    allow_spinning: bool = False
    providers: tuple[str, ...] = ("CPUExecutionProvider",)
    nms: str = "auto"
    quantize_int8: bool = False
    cache_dir: Path | None = None


@dataclass(frozen=True)
class PreparedSession:
    """The session, whether its graph ends before the SSD's NMS, and the cached graph file it came from (if any)."""

    session: Any
    ssd_head: bool
    cache_path: Path | None
    cache_hit: bool


def default_cache_dir() -> Path:
    """`$XDG_CACHE_HOME/changing_slam_ros/onnx` (`~/.cache/...` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "changing_slam_ros" / "onnx"


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def session_options(settings: SessionSettings, level: str | None = None) -> Any:
    """onnxruntime SessionOptions: thread counts, sequential execution, optimisation level, spinning."""
    import onnxruntime as ort

    levels = {
        "disable": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    }
    options = ort.SessionOptions()
    if settings.intra_op_threads > 0:
        options.intra_op_num_threads = settings.intra_op_threads
        options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = levels[level or settings.graph_optimization]
    # Spinning threads wait for work by busy-looping: a little faster alone, much slower when the detector
    # shares the cores with tracking (measured in bench/bench_detector.py).
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if settings.allow_spinning else "0")
    options.log_severity_level = 3
    return options


def cut_before_ssd_nms(model_bytes: bytes) -> bytes | None:
    """The graph up to `SSD_HEAD_OUTPUTS` (serialised), or None when the model has no such tensors."""
    import onnx

    model = onnx.load_model_from_string(model_bytes)
    graph = model.graph
    producer = {out: node for node in graph.node for out in node.output}
    if not all(name in producer for name in SSD_HEAD_OUTPUTS):
        return None
    needed: set[int] = set()
    stack = list(SSD_HEAD_OUTPUTS)
    while stack:
        node = producer.get(stack.pop())
        if node is None or id(node) in needed:
            continue
        needed.add(id(node))
        stack.extend(name for name in node.input if name)
    nodes = [node for node in graph.node if id(node) in needed]
    used = {name for node in nodes for name in node.input}
    for node in nodes:  # names read inside a kept node's subgraphs (the preprocessing loop)
        for attr in node.attribute:
            if attr.type == onnx.AttributeProto.GRAPH:
                used.update(name for sub in attr.g.node for name in sub.input)
    initializers = [init for init in graph.initializer if init.name in used]
    del graph.node[:]
    graph.node.extend(nodes)
    del graph.initializer[:]
    graph.initializer.extend(initializers)
    del graph.output[:]
    graph.output.extend(onnx.helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, None) for n in SSD_HEAD_OUTPUTS)
    kept_info = [vi for vi in graph.value_info if vi.name in used or vi.name in SSD_HEAD_OUTPUTS]
    del graph.value_info[:]
    graph.value_info.extend(kept_info)
    return bytes(model.SerializeToString())


def quantize_int8(model_bytes: bytes, workdir: Path) -> bytes:
    """Dynamic INT8 quantisation (weights int8, activations quantised per call) of a serialised graph."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    src, dst = workdir / "fp32.onnx", workdir / "int8.onnx"
    src.write_bytes(model_bytes)
    quantize_dynamic(str(src), str(dst), weight_type=QuantType.QUInt8)
    return dst.read_bytes()


def cache_key(sha256: str, settings: SessionSettings, provider: str) -> str:
    """File name of a prepared graph: model hash, onnxruntime version, provider and variant."""
    import onnxruntime as ort

    variant = {"graph": "full", "numpy": "head", "auto": "auto"}[settings.nms] + ("-int8" if settings.quantize_int8 else "")
    return f"{sha256[:16]}-ort{ort.__version__}-{provider.replace('ExecutionProvider', '').lower()}-{variant}.onnx"


def _is_ssd_head(session: Any) -> bool:
    return [o.name for o in session.get_outputs()] == list(SSD_HEAD_OUTPUTS)


def prepare_session(model_path: Path, settings: SessionSettings) -> PreparedSession:
    """Load `model_path` into an onnxruntime session as `settings` say, through the cache when there is one."""
    import onnxruntime as ort

    if settings.graph_optimization not in GRAPH_OPTIMIZATIONS:
        raise ConfigError(f"detector.graph_optimization: {settings.graph_optimization!r} is not one of {GRAPH_OPTIMIZATIONS}")
    if settings.nms not in NMS_MODES:
        raise ConfigError(f"detector.nms: {settings.nms!r} is not one of {', '.join(NMS_MODES)}")
    available = set(ort.get_available_providers())
    providers = [p for p in settings.providers if p in available] or ["CPUExecutionProvider"]

    def load(source: str | bytes) -> Any:
        try:
            return ort.InferenceSession(source, sess_options=session_options(settings), providers=providers)
        except Exception as err:  # noqa: BLE001 - onnxruntime raises its own exception types
            raise ConfigError(f"detector.model_path: {model_path}: onnxruntime cannot load it ({err})") from err

    plain = settings.nms == "graph" and not settings.quantize_int8
    if plain and settings.cache_dir is None:
        session = load(str(model_path))
        return PreparedSession(session, False, None, False)

    cache_path = None
    if settings.cache_dir is not None:
        cache_path = settings.cache_dir / cache_key(file_sha256(model_path), settings, providers[0])
        if cache_path.is_file():
            try:
                session = load(str(cache_path))
                return PreparedSession(session, _is_ssd_head(session), cache_path, True)
            except ConfigError:  # an unreadable cached graph (another onnxruntime build wrote it): make it again
                cache_path.unlink(missing_ok=True)

    graph = model_path.read_bytes()
    if settings.nms != "graph":
        head = cut_before_ssd_nms(graph)
        if head is None and settings.nms == "numpy":
            raise ConfigError(
                f"detector.nms: numpy needs a TF-OD SSD graph with tensors {', '.join(SSD_HEAD_OUTPUTS)}; "
                f"{model_path} has none (use nms: graph or auto)"
            )
        graph = head or graph
    with tempfile.TemporaryDirectory(prefix="detector-") as tmp:
        if settings.quantize_int8:
            graph = quantize_int8(graph, Path(tmp))
        if cache_path is None:
            session = load(graph)
            return PreparedSession(session, _is_ssd_head(session), None, False)
        try:
            _save_optimised(graph, cache_path, settings, providers)
        except OSError:  # a read-only or full cache folder: run without the cache
            session = load(graph)
            return PreparedSession(session, _is_ssd_head(session), None, False)
    session = load(str(cache_path))
    return PreparedSession(session, _is_ssd_head(session), cache_path, False)


def _save_optimised(graph: bytes, cache_path: Path, settings: SessionSettings, providers: list[str]) -> None:
    """Optimise `graph` at the portable `extended` level and write it to `cache_path` atomically."""
    import onnxruntime as ort

    from changing_slam_ros.io.atomic import atomic_write_bytes

    cache_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{cache_path.name}.", dir=cache_path.parent) as tmp:
        written = Path(tmp) / "optimised.onnx"  # onnxruntime writes the file itself, by path
        options = session_options(settings, level="extended")
        options.optimized_model_filepath = str(written)
        ort.InferenceSession(graph, sess_options=options, providers=providers)
        atomic_write_bytes(cache_path, written.read_bytes())
