"""The detector's onnxruntime session: session options, the SSD graph without its in-graph NMS (slimmed), and a cache.

TensorFlow Object Detection exports (the shipped SSD-MobileNetV2) end in a per-class non-maximum suppression
that tf2onnx turns into a loop of about 7,000 small nodes over the 90 classes. Running them costs about as much
as a quarter of the network and optimising them at load time about 18 s. `prepare_session` can cut the graph at
the decoded boxes and sigmoid scores (`SSD_HEAD_OUTPUTS`) so that the detector does the suppression in numpy
(`detector.postprocess_ssd_head`), which gives the same detections. `slim_ssd_head` then removes the
preprocessing loop and the class predictors' output channels that are never reported (background, COCO ids
without a class): the kept scores are bit-identical and about 10 % of the CPU time goes.

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
    - `ssd_class_columns`: with the graph cut before the NMS, also slim it (`slim_ssd_head`), keeping these
      score columns (indices into background + 90 COCO ids); empty = no slimming.
    - `spin_duration_us`: with `allow_spinning`, how long an idle pool thread spins before it sleeps
      (onnxruntime's `session.intra_op.spin_duration_us`); 0 = onnxruntime's default.
    """

    intra_op_threads: int = 2
    graph_optimization: str = "all"
    allow_spinning: bool = False
    providers: tuple[str, ...] = ("CPUExecutionProvider",)
    nms: str = "auto"
    quantize_int8: bool = False
    cache_dir: Path | None = None
    ssd_class_columns: tuple[int, ...] = ()
    spin_duration_us: int = 0


@dataclass(frozen=True)
class PreparedSession:
    """The session, whether its graph ends before the SSD's NMS, the cached graph file it came from (if any), and
    for a slimmed SSD head (`slim_ssd_head`) the original score column of each of its score columns."""

    session: Any
    ssd_head: bool
    cache_path: Path | None
    cache_hit: bool
    score_columns: tuple[int, ...] | None = None


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
    if settings.allow_spinning and settings.spin_duration_us > 0:
        options.add_session_config_entry("session.intra_op.spin_duration_us", str(settings.spin_duration_us))
    options.log_severity_level = 3
    return options


def cut_before_ssd_nms(model_bytes: bytes) -> bytes | None:
    """The graph up to `SSD_HEAD_OUTPUTS` (serialised), or None when the model has no such tensors."""
    import onnx

    model = onnx.load_model_from_string(model_bytes)
    graph = model.graph
    produced = {out for node in graph.node for out in node.output}
    if not all(name in produced for name in SSD_HEAD_OUTPUTS):
        return None
    _keep_needed(graph, list(SSD_HEAD_OUTPUTS))
    del graph.output[:]
    graph.output.extend(onnx.helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, None) for n in SSD_HEAD_OUTPUTS)
    used = _names_read(graph)
    kept_info = [vi for vi in graph.value_info if vi.name in used or vi.name in SSD_HEAD_OUTPUTS]
    del graph.value_info[:]
    graph.value_info.extend(kept_info)
    return bytes(model.SerializeToString())


def _names_read(graph: Any) -> set[str]:
    """Every tensor name the nodes of `graph` read, including names read inside their subgraphs (a Loop body)."""
    import onnx

    used = {name for node in graph.node for name in node.input}
    for node in graph.node:
        for attr in node.attribute:
            if attr.type == onnx.AttributeProto.GRAPH:
                used.update(name for sub in attr.g.node for name in sub.input)
    return used


def _keep_needed(graph: Any, outputs: list[str]) -> None:
    """Drop (in place) the nodes and initializers of `graph` that `outputs` do not depend on."""
    import onnx

    producer = {out: node for node in graph.node for out in node.output}
    needed: set[int] = set()
    stack = list(outputs)
    while stack:
        node = producer.get(stack.pop())
        if node is None or id(node) in needed:
            continue
        needed.add(id(node))
        stack.extend(name for name in node.input if name)
        for attr in node.attribute:  # names read inside a kept node's subgraphs (a Loop body)
            if attr.type == onnx.AttributeProto.GRAPH:
                stack.extend(name for sub in attr.g.node for name in sub.input if name)
    nodes = [node for node in graph.node if id(node) in needed]
    del graph.node[:]
    graph.node.extend(nodes)
    used = _names_read(graph)
    initializers = [init for init in graph.initializer if init.name in used]
    del graph.initializer[:]
    graph.initializer.extend(initializers)


def slim_ssd_head(head_bytes: bytes, class_columns: tuple[int, ...]) -> bytes | None:
    """The SSD head graph (`cut_before_ssd_nms`) with two kinds of waste removed, or None when it does not have
    the TF-OD layout this expects:

    - the preprocessing `Loop` (TF's `map` over the batch: per image a Gather, Shape arithmetic, a transpose
      and a resize of the full-size float image) becomes one Resize + Transpose for a batch of one, with the
      same Resize attributes (asymmetric bilinear, TF1's `resize_bilinear`); the input is fixed to
      (1, H, W, 3), which makes every shape downstream static, so onnxruntime folds the Shape/Slice/Concat
      chains of the box predictors;
    - the class predictors (3x3 convolutions, about 55 % of the network's multiply-adds) compute only the
      score columns `class_columns` (indices into the 1 + 90 columns, background in 0): the background and
      the COCO ids with no class are never reported, so their output channels are cut from the weights.
      The scores output then has `len(class_columns)` columns, in that order.
    """
    import numpy as np
    import onnx
    from onnx import helper, numpy_helper

    model = onnx.load_model_from_string(head_bytes)
    graph = model.graph
    inits = {init.name: init for init in graph.initializer}
    consumers: dict[str, list[Any]] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    loops = [n for n in graph.node if n.op_type == "Loop"]
    if len(loops) != 1 or len(graph.input) != 1:
        return None
    loop = loops[0]
    body = next(a.g for a in loop.attribute if a.name == "body")
    resizes = [n for n in body.node if n.op_type == "Resize"]
    image = graph.input[0].name
    cast = next((n for n in consumers.get(image, []) if n.op_type == "Cast"), None)
    if len(resizes) != 1 or cast is None or len(loop.output) < 2:
        return None
    resize = resizes[0]
    body_producer = {out: node for node in body.node for out in node.output}
    sizes_concat = body_producer.get(resize.input[3]) if len(resize.input) > 3 else None
    if sizes_concat is None or sizes_concat.op_type != "Concat" or len(sizes_concat.input) != 2:
        return None
    hw_init = inits.get(sizes_concat.input[1]) or next(
        (i for i in body.initializer if i.name == sizes_concat.input[1]), None
    )
    if hw_init is None:
        return None
    out_hw = [int(v) for v in numpy_helper.to_array(hw_init).reshape(-1)]
    if len(out_hw) != 2:
        return None

    # Class predictor convolutions: (A * 91) output channels, anchor-major, cut to A * len(class_columns).
    n_cols = 91
    cols = np.asarray(class_columns, dtype=np.int64)
    reshapes: list[Any] = []
    for node in graph.node:
        if node.op_type != "Conv" or "/ClassPredictor/" not in node.name or len(node.input) < 3:
            continue
        w_init, b_init = inits.get(node.input[1]), inits.get(node.input[2])
        if w_init is None or b_init is None or w_init.dims[0] % n_cols:
            return None
        rows = (np.arange(w_init.dims[0] // n_cols)[:, None] * n_cols + cols[None, :]).reshape(-1)
        for init, pos in ((w_init, 1), (b_init, 2)):
            sliced = numpy_helper.from_array(numpy_helper.to_array(init)[rows], f"{init.name}/slim")
            graph.initializer.append(sliced)
            node.input[pos] = sliced.name
        nxt = consumers.get(node.output[0], [])
        if len(nxt) == 1 and nxt[0].op_type == "Transpose":
            nxt = consumers.get(nxt[0].output[0], [])
        if len(nxt) != 1 or nxt[0].op_type != "Reshape":
            return None
        reshapes.append(nxt[0])
    if not reshapes:
        return None
    shape_name = "slim/class_scores_shape"
    graph.initializer.append(numpy_helper.from_array(np.array([1, -1, len(cols)], np.int64), shape_name))
    for node in reshapes:
        node.input[1] = shape_name

    # The preprocessing: the NHWC float image resized (same values as the loop's resize of the NCHW image, per
    # channel), then the small result transposed to NCHW, as the loop's stacked output.
    attrs = {a.name: helper.get_attribute_value(a) for a in resize.attribute}
    sizes_name = "slim/resize_sizes"
    graph.initializer.append(numpy_helper.from_array(np.array([1, *out_hw, 3], np.int64), sizes_name))
    new_nodes = [
        helper.make_node("Resize", [cast.output[0], "", "", sizes_name], ["slim/resized"], name="slim/Resize", **attrs),
        helper.make_node("Transpose", ["slim/resized"], [loop.output[1]], name="slim/Transpose", perm=[0, 3, 1, 2]),
    ]
    graph.node.remove(loop)
    graph.node.extend(new_nodes)
    dims = graph.input[0].type.tensor_type.shape.dim
    if len(dims) != 4:
        return None
    for dim, value in zip(dims, (1, "height", "width", 3)):
        dim.Clear()
        if isinstance(value, int):
            dim.dim_value = value
        else:
            dim.dim_param = value
    del graph.value_info[:]
    _keep_needed(graph, [o.name for o in graph.output])
    _toposort(graph)
    return bytes(model.SerializeToString())


def _toposort(graph: Any) -> None:
    """Order `graph.node` so every node comes after the producers of its inputs (ONNX requires it)."""
    producer = {out: i for i, node in enumerate(graph.node) for out in node.output}
    order: list[int] = []
    state: dict[int, int] = {}
    for start in range(len(graph.node)):
        stack = [(start, False)]
        while stack:
            i, done = stack.pop()
            if done:
                state[i] = 2
                order.append(i)
                continue
            if state.get(i):
                continue
            state[i] = 1
            stack.append((i, True))
            node = graph.node[i]
            deps = list(node.input)
            for attr in node.attribute:
                if attr.g is not None:
                    deps.extend(name for sub in attr.g.node for name in sub.input)
            stack.extend((producer[d], False) for d in deps if d in producer and not state.get(producer[d]))
    nodes = [graph.node[i] for i in order]
    del graph.node[:]
    graph.node.extend(nodes)


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

    variant = {"graph": "full", "numpy": "head", "auto": "auto"}[settings.nms]
    if settings.nms != "graph" and settings.ssd_class_columns:  # slimmed; "v2": bump when slim_ssd_head changes
        columns = hashlib.sha256(",".join(map(str, settings.ssd_class_columns)).encode()).hexdigest()[:8]
        variant += f"-slim{len(settings.ssd_class_columns)}.{columns}.v2"
    variant += "-int8" if settings.quantize_int8 else ""
    return f"{sha256[:16]}-ort{ort.__version__}-{provider.replace('ExecutionProvider', '').lower()}-{variant}.onnx"


def _is_ssd_head(ort_session: Any) -> bool:
    return [o.name for o in ort_session.get_outputs()] == list(SSD_HEAD_OUTPUTS)


def _prepared(ort_session: Any, settings: SessionSettings, cache_path: Path | None, hit: bool) -> PreparedSession:
    """A `PreparedSession`; a head whose scores have one column per kept class is the slimmed graph."""
    head = _is_ssd_head(ort_session)
    columns = None
    if head and settings.ssd_class_columns:
        shape = ort_session.get_outputs()[1].shape
        if shape and shape[-1] == len(settings.ssd_class_columns):
            columns = tuple(settings.ssd_class_columns)
    return PreparedSession(ort_session, head, cache_path, hit, columns)


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
        ort_session = load(str(model_path))
        return PreparedSession(ort_session, False, None, False)

    cache_path = None
    if settings.cache_dir is not None:
        cache_path = settings.cache_dir / cache_key(file_sha256(model_path), settings, providers[0])
        if cache_path.is_file():
            try:
                ort_session = load(str(cache_path))
                return _prepared(ort_session, settings, cache_path, True)
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
        if head is not None and settings.ssd_class_columns:
            head = slim_ssd_head(head, settings.ssd_class_columns) or head
        graph = head or graph
    with tempfile.TemporaryDirectory(prefix="detector-") as tmp:
        if settings.quantize_int8:
            graph = quantize_int8(graph, Path(tmp))
        if cache_path is None:
            return _prepared(load(graph), settings, None, False)
        try:
            _save_optimised(graph, cache_path, settings, providers)
        except OSError:  # a read-only or full cache folder: run without the cache
            return _prepared(load(graph), settings, None, False)
    return _prepared(load(str(cache_path)), settings, cache_path, False)


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
