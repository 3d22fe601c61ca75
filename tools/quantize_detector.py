#!/usr/bin/env python3
"""Make the shipped INT8 detector (changing_slam_ros/models/ssd_mobilenet_v2_coco_int8.onnx) from the fp32 SSD.

Steps, all deterministic (same inputs and library versions give a byte-identical file):

1. the fp32 SSD-MobileNetV2 graph is cut before its per-class NMS (`detector_session.cut_before_ssd_nms`) and
   slimmed (`slim_ssd_head`: one Resize for the preprocessing loop, only the 80 classes' score channels), i.e.
   the graph the detector runs by default; the NMS is done in numpy by `detector.postprocess_ssd_head`;
2. onnxruntime's quantisation pre-processing (`quant_pre_process`: shape inference, basic graph optimisation,
   which folds the depthwise convolutions' batch-norm Mul/Add into their weights);
3. static post-training quantisation (`quantize_static`), QDQ format, per-channel int8 weights, uint8
   activations, MinMax calibration, of the backbone and class-predictor nodes only: every Conv (the graph has
   no other; tf2onnx named the 1x1 ones `Conv__NNNN`) except the six box-encoding predictors', and the ReLU6
   Clips and residual Adds under `FeatureExtractor/` and `BoxPredictor_*/`; the preprocessing (cast, resize,
   normalisation), the box-encoding convolutions (3 % of the multiply-adds; fp32 they raise the median IoU
   with fp32's boxes from 0.96 to 0.97 and the smallest on the TUM reference frame from 0.80 to 0.86) and the
   postprocessing (anchor decoding, sigmoid) stay fp32.

Calibration images are only ones a derived model may be redistributed with (no 7-Scenes material):
- the bundled bags `bags/tum_fr1_xyz_first10.mcap` (TUM RGB-D freiburg1_xyz, CC BY 4.0, TUM CVG) and
  `bags/sim_walking_changing.mcap` (the project's simulator, Apache-2.0), read with the project's readers;
- simulator renders (`changing-slam simulate`, seed 0, 640x480) of the scenarios in `--scenarios`, rendered by
  this tool into a temporary folder. The scenarios the recall bench evaluates on (walking_xyz,
  walking_halfsphere, sitting_xyz) are deliberately not among the defaults.

    .venv/bin/python tools/quantize_detector.py --out changing_slam_ros/models/ssd_mobilenet_v2_coco_int8.onnx
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.dynamic.detector import COCO91_IDS, DEFAULT_MODEL_PATH  # noqa: E402
from changing_slam_ros.core.dynamic.detector_session import SSD_HEAD_OUTPUTS, cut_before_ssd_nms, slim_ssd_head  # noqa: E402
from changing_slam_ros.io.atomic import atomic_write_bytes  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402

DEFAULT_BAGS = (
    (REPO / "bags" / "tum_fr1_xyz_first10.mcap", "tum_fr1", 1),
    (REPO / "bags" / "sim_walking_changing.mcap", "sim", 5),
)
DEFAULT_SCENARIOS = ("walking_static", "walking_rpy", "changing", "one_chair")
QUANTISED_PREFIXES = ("FeatureExtractor/", "BoxPredictor_")
QUANTISED_OPS = ("Clip", "Add")  # under QUANTISED_PREFIXES; every Conv is quantised


@dataclass(frozen=True)
class CalibrationSource:
    """Every `stride`-th colour frame of a bag or TUM-layout folder, read with `config`'s dataset settings."""

    path: Path
    config: str
    stride: int


def calibration_frames(sources: list[CalibrationSource]) -> Iterator[tuple[str, np.ndarray]]:
    """(label, RGB (H, W, 3) uint8) in the order of `sources`, then of their frames."""
    for src in sources:
        for k, rgbd in enumerate(open_dataset(src.path, src.config)):
            if k % src.stride == 0:
                yield f"{src.path.name}#{k}", np.ascontiguousarray(rgbd.rgb, dtype=np.uint8)


def render_scenarios(scenarios: tuple[str, ...], frames: int, out_root: Path) -> list[Path]:
    """Render each scenario (seed 0, 640x480, `frames` frames) with the project's CLI; the folders. A folder
    that already holds a finished render of `frames` frames (its `rgb.txt`) is reused."""
    cli = Path(sys.executable).parent / "changing-slam"
    folders = []
    for name in scenarios:
        folder = out_root / name
        listing = folder / "rgb.txt"
        if listing.is_file() and sum(1 for ln in listing.read_text().splitlines() if ln and not ln.startswith("#")) == frames:
            folders.append(folder)
            continue
        cmd = [str(cli), "simulate", name, "--out", str(folder), "--frames", str(frames), "--width", "640",
               "--height", "480", "--seed", "0", "--quiet"]  # fmt: skip
        subprocess.run(cmd, check=True)
        folders.append(folder)
    return folders


def head_graph(model_path: Path) -> bytes:
    """The fp32 graph the detector runs: cut before the NMS, slimmed to the 80 classes."""
    head = cut_before_ssd_nms(model_path.read_bytes())
    if head is None:
        raise SystemExit(f"{model_path}: not a TF-OD SSD graph (no {', '.join(SSD_HEAD_OUTPUTS)})")
    slim = slim_ssd_head(head, COCO91_IDS)
    if slim is None:
        raise SystemExit(f"{model_path}: the SSD head does not have the layout slim_ssd_head expects")
    return slim


def quantised_node_names(model_path: Path, fp32_box_encoders: bool) -> list[str]:
    """Names of the nodes to quantise, in graph order: every Conv (but the box-encoding predictors' with
    `fp32_box_encoders`), and QUANTISED_OPS in the backbone and box predictors."""
    import onnx

    graph = onnx.load(str(model_path)).graph
    return [
        n.name
        for n in graph.node
        if (n.op_type == "Conv" and not (fp32_box_encoders and "/BoxEncodingPredictor/" in n.name))
        or (n.op_type in QUANTISED_OPS and n.name.startswith(QUANTISED_PREFIXES))
    ]


def fix_scores_shape(model_bytes: bytes, n_columns: int) -> bytes:
    """Declare the outputs' static parts (boxes (1, A, 4), scores (1, A, n_columns)) so a loader can tell the
    slimmed head's score columns from the declared shape, with or without onnxruntime's shape inference."""
    import onnx

    model = onnx.load_model_from_string(model_bytes)
    for out, last in zip(model.graph.output, (4, n_columns)):
        dims = out.type.tensor_type.shape.dim
        del dims[:]
        for value in (1, "anchors", last):
            dim = dims.add()
            if isinstance(value, int):
                dim.dim_value = value
            else:
                dim.dim_param = value
    return bytes(model.SerializeToString())


class _Reader:
    """onnxruntime CalibrationDataReader over pre-loaded frames."""

    def __init__(self, input_name: str, frames: list[np.ndarray]) -> None:
        self._feeds = iter([{input_name: f[None]} for f in frames])

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._feeds, None)


@dataclass(frozen=True)
class QuantSettings:
    """`quantize_static` choices: weights per channel or per tensor, QDQ or QOperator format, calibration
    method (minmax, percentile, entropy), box-encoding predictors left fp32."""

    per_channel: bool = True
    fmt: str = "qdq"
    calibration: str = "minmax"
    fp32_box_encoders: bool = True


def quantise(model_path: Path, frames: list[np.ndarray], workdir: Path, settings: QuantSettings) -> bytes:
    """Steps 1-3 of the module docstring; the serialised INT8 model."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
               "entropy": CalibrationMethod.Entropy}  # fmt: skip
    head = workdir / "head_fp32.onnx"
    head.write_bytes(head_graph(model_path))
    pre = workdir / "head_fp32_pre.onnx"
    quant_pre_process(str(head), str(pre), skip_symbolic_shape=True)
    out = workdir / "head_int8.onnx"
    quantize_static(
        str(pre),
        str(out),
        _Reader("image_tensor:0", frames),
        quant_format=QuantFormat.QDQ if settings.fmt == "qdq" else QuantFormat.QOperator,
        per_channel=settings.per_channel,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        nodes_to_quantize=quantised_node_names(pre, settings.fp32_box_encoders),
        calibrate_method=methods[settings.calibration],
    )
    return fix_scores_shape(out.read_bytes(), len(COCO91_IDS))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_PATH, help="fp32 TF-OD SSD ONNX model")
    parser.add_argument("--out", type=Path, required=True, help="INT8 model to write")
    parser.add_argument("--scenarios", nargs="*", default=list(DEFAULT_SCENARIOS), help="simulator scenarios to render")
    parser.add_argument("--sim-frames", type=int, default=150, help="frames rendered per scenario")
    parser.add_argument("--sim-stride", type=int, default=5, help="every N-th rendered frame calibrates")
    parser.add_argument("--sim-root", type=Path, default=None, help="render here and reuse finished renders (default: a temporary folder)")
    parser.add_argument("--no-bags", action="store_true", help="calibrate on the renders only")
    parser.add_argument("--format", choices=("qdq", "qoperator"), default="qdq")
    parser.add_argument("--per-tensor", action="store_true", help="per-tensor instead of per-channel weights")
    parser.add_argument("--calibration", choices=("minmax", "percentile", "entropy"), default="minmax",
                        help="percentile and entropy keep every tensor's values of every frame: with the default 174 "
                        "frames percentile was killed out of memory at 20 GB on a 23 GB machine")
    parser.add_argument("--int8-box-encoders", action="store_true", help="quantise the box-encoding convolutions too")
    args = parser.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="quantize-detector-") as tmp:
        sim_root = args.sim_root or Path(tmp) / "sim"
        sources = [] if args.no_bags else [CalibrationSource(p, c, s) for p, c, s in DEFAULT_BAGS]
        folders = render_scenarios(tuple(args.scenarios), args.sim_frames, sim_root)
        sources += [CalibrationSource(f, "sim", args.sim_stride) for f in folders]
        labelled = list(calibration_frames(sources))
        counts: dict[str, int] = {}
        for label, _ in labelled:
            counts[label.split("#")[0]] = counts.get(label.split("#")[0], 0) + 1
        print(f"calibration: {len(labelled)} frames ({', '.join(f'{k} {v}' for k, v in counts.items())})", flush=True)
        settings = QuantSettings(not args.per_tensor, args.format, args.calibration, not args.int8_box_encoders)
        data = quantise(args.model, [f for _, f in labelled], Path(tmp), settings)
    atomic_write_bytes(args.out, data)
    digest = hashlib.sha256(data).hexdigest()
    print(f"wrote {args.out}: {len(data) / 1e6:.2f} MB, sha256 {digest} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
