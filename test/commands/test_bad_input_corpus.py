"""A corpus of bad input, generated here: each case must end the command with exit 1 and one line on stderr that
names the file, field or parameter at fault, never a traceback. Add a case for every new kind of bad input."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from helpers import FR1_XYZ_10

from changing_slam_ros.cli import main as cli_main

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"
GOOD_CAMERA = "camera:\n  width: 640\n  height: 480\n  fx: 517.3\n  fy: 516.5\n  cx: 318.6\n  cy: 255.3\n"
TRAJ = "1.0 0 0 0 0 0 0 1\n2.0 0.1 0 0 0 0 0 1\n3.0 0.2 0 0 0 0 0 1\n"


@dataclass(frozen=True)
class Case:
    name: str
    files: dict[str, str | bytes]  # written into the case folder first (name -> text or bytes)
    argv: Callable[[Path], list[str]]  # the command line, given the case folder
    expect: Callable[[Path], list[str]]  # substrings of the one error line
    needs_fr1: bool = False  # the case folder starts as a copy of the fr1 TUM folder (files then overwrite)
    drop: tuple[str, ...] = ()  # files of that copy removed first (associations.txt, so rgb.txt is read)
    prepare: Callable[[Path], object] | None = None  # writes what `files` cannot hold (a bag, a cut file)


def config_case(name: str, text: str | bytes, *expect: str) -> list[Case]:
    """The same bad config given to `run` and to `graph` (checked before any process starts)."""
    return [
        Case(f"run-config-{name}", {"bad.yaml": text},
             lambda d: ["run", str(BAG), "--out", str(d / "out"), "--config", str(d / "bad.yaml"), "--quiet"],
             lambda d: ["bad.yaml", *expect]),
        Case(f"graph-config-{name}", {"bad.yaml": text},
             lambda d: ["graph", str(BAG), "--out", str(d / "out"), "--config", str(d / "bad.yaml")],
             lambda d: ["bad.yaml", *expect]),
    ]  # fmt: skip


def eval_case(name: str, gt: str | bytes, est: str | bytes, *expect: str) -> Case:
    return Case(f"eval-{name}", {"gt.txt": gt, "est.txt": est},
                lambda d: ["eval", "ate", str(d / "gt.txt"), str(d / "est.txt")], lambda d: list(expect))  # fmt: skip


def tum_case(name: str, files: dict[str, str | bytes], *expect: str,
             prepare: Callable[[Path], object] | None = None) -> Case:  # fmt: skip
    drop = ("associations.txt",) if set(files) & {"rgb.txt", "depth.txt"} else ()
    return Case(f"tum-{name}", files, lambda d: ["run", str(d), "--out", str(d.parent / f"{d.name}-out"),
                                                 "--config", "tum_fr1", "--quiet"],
                lambda d: list(expect), needs_fr1=True, drop=drop, prepare=prepare)  # fmt: skip


def _cut_first_colour_png(folder: Path) -> None:
    png = sorted((folder / "rgb").glob("*.png"))[0]
    png.write_bytes(png.read_bytes()[:2000])


def _cut_bag(size: int) -> Callable[[Path], object]:
    return lambda d: (d / "cut.mcap").write_bytes(BAG.read_bytes()[:size])


def _bad_image_bag(folder: Path) -> None:
    from helpers import write_bag_with_one_bad_image

    write_bag_with_one_bad_image(folder / "one_bad.mcap")


CAMERA_INFO_YAML = "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [%s]}\n"


def out_case(name: str, files: dict[str, str | bytes], out: str, command: str, *expect: str) -> Case:
    source = [str(BAG)] if command in ("run", "graph") else []
    return Case(f"{command}-out-{name}", files,
                lambda d: [command, *source, "--out", str(d / out), "--config", "tum_fr1"], lambda d: [out, *expect])


RGB_BAD_BYTE = b"# colour images\n1305031102.175304 rgb/1305031102.175304.png\n1305031102.211\xff rgb/x.png\n"
NOT_A_MAP = b"PK\x03\x04 not really a zip"


def _npz_without_version() -> bytes:
    import io

    import numpy as np

    buf = io.BytesIO()
    np.savez(buf, m0_kf_ids=np.arange(3))
    return buf.getvalue()


CASES: list[Case] = [
    # configs: values, sections, files
    *config_case("fx-nan", GOOD_CAMERA.replace("517.3", ".nan"), "camera", "fx nan", "finite"),
    *config_case("fy-inf", GOOD_CAMERA.replace("516.5", ".inf"), "camera", "fy inf", "finite"),
    *config_case("dist-2", GOOD_CAMERA + "  dist: [0.2, 0.1]\n", "camera", "dist: 2 values", "4, 5 or 8"),
    *config_case("dist-3", GOOD_CAMERA + "  dist: [0.2, 0.1, 0.0]\n", "dist: 3 values"),
    *config_case("dist-nan", GOOD_CAMERA + "  dist: [0.2, .nan, 0, 0, 0]\n", "dist", "finite"),
    *config_case("fx-negative", GOOD_CAMERA.replace("517.3", "-517.3"), "camera", "fx=-517.3"),
    *config_case("fx-text", GOOD_CAMERA.replace("517.3", "abc"), "camera.fx", "expected a number"),
    *config_case("section-typo", "trackng:\n  max_frames_between_keyframes: 3\n", "trackng", "did you mean tracking"),
    *config_case("section-typo-camera", "camra:\n  fx: 1\n", "camra", "did you mean camera"),
    *config_case("unknown-key", "tracking:\n  no_such_key: 1\n", "tracking", "no_such_key"),
    *config_case("depth-scale-0", "dataset:\n  depth_scale: 0\n", "depth_scale"),
    *config_case("depth-scale-nan", "dataset:\n  depth_scale: .nan\n", "depth_scale"),
    *config_case("topic-preset", "dataset:\n  topic_preset: kinect9\n", "topic_preset", "kinect9"),
    *config_case("list-top-level", "- camera\n- dataset\n", "mapping of sections"),
    *config_case("not-yaml", "camera: [1, 2\n", "not valid YAML"),
    *config_case("not-utf8", b"camera:\n  fx: 5\xff17\n", "bad.yaml:2: not UTF-8"),
    Case("run-config-missing", {}, lambda d: ["run", str(BAG), "--out", str(d / "o"), "--config", str(d / "no.yaml")],
         lambda d: ["no.yaml", "no such config"]),  # fmt: skip
    # TUM folders: text files that are not text, malformed rows
    tum_case("rgb-non-utf8", {"rgb.txt": RGB_BAD_BYTE}, "rgb.txt:3: not UTF-8", "0xff"),
    tum_case("groundtruth-non-utf8", {"groundtruth.txt": b"# gt\n1305031102.1 1 2 3 0 0 0 1\n\xfe\xff\n"},
             "groundtruth.txt:3: not UTF-8"),
    tum_case("depth-binary", {"depth.txt": bytes(range(256))}, "depth.txt:2: not UTF-8"),
    tum_case("rgb-bad-stamp", {"rgb.txt": "# x\nabc rgb/1.png\n"}, "rgb.txt:2", "abc"),
    tum_case("associations-non-utf8", {"associations.txt": b"1305031102.175304 rgb/a.png 1305031102.1\xe9 d.png\n"},
             "associations.txt:1: not UTF-8"),
    tum_case("colour-png-truncated", {}, "colour image is truncated", prepare=_cut_first_colour_png),
    # intrinsics shipped with the data (7-Scenes camera-intrinsics.txt, camera_info.yaml)
    tum_case("intrinsics-txt-two-rows", {"camera-intrinsics.txt": "585 0 320\n0 585 240\n"},
             "camera-intrinsics.txt: expected a 3x3 camera matrix"),
    tum_case("intrinsics-txt-word", {"camera-intrinsics.txt": "585 0 320\n0 f 240\n0 0 1\n"},
             "camera-intrinsics.txt:2: camera matrix values must be numbers"),
    tum_case("intrinsics-txt-non-utf8", {"camera-intrinsics.txt": b"5\xe885 0 320\n0 585 240\n0 0 1\n"},
             "camera-intrinsics.txt:1: not UTF-8"),
    tum_case("intrinsics-txt-fx-0", {"camera-intrinsics.txt": "0 0 320\n0 585 240\n0 0 1\n"},
             "camera-intrinsics.txt", "fx=0.0"),
    tum_case("camera-info-yaml-non-utf8", {"camera_info.yaml": b"image_width: 640\n\xff\n"},
             "camera_info.yaml:2: not UTF-8"),
    tum_case("camera-info-yaml-broken", {"camera_info.yaml": "image_width: [640\n"},
             "camera_info.yaml:2: not valid YAML"),
    tum_case("camera-info-yaml-no-matrix", {"camera_info.yaml": "image_width: 640\nimage_height: 480\n"},
             "camera_info.yaml", "missing key 'camera_matrix'"),
    tum_case("camera-info-yaml-fx-0", {"camera_info.yaml": CAMERA_INFO_YAML % "0, 0, 320, 0, 585, 240, 0, 0, 1"},
             "camera_info.yaml", "fx=0.0"),
    tum_case("camera-info-yaml-model", {"camera_info.yaml": CAMERA_INFO_YAML % "585, 0, 320, 0, 585, 240, 0, 0, 1"
             + "distortion_model: equidistant\ndistortion_coefficients: {rows: 1, cols: 4, data: [0.1, 0, 0, 0]}\n"},
             "camera_info.yaml", "distortion model 'equidistant' unsupported"),
    # eval: binary, missing, empty, malformed
    eval_case("est-binary", TRAJ, bytes(range(256)) * 4, "est.txt:2: not UTF-8"),
    eval_case("gt-binary", b"\x89PNG\r\n\x1a\n" + bytes(100), TRAJ, "gt.txt:1: not UTF-8"),
    Case("eval-gt-missing", {"est.txt": TRAJ}, lambda d: ["eval", "ate", str(d / "gt.txt"), str(d / "est.txt")],
         lambda d: ["gt.txt"]),  # fmt: skip
    eval_case("est-empty", TRAJ, "", "est.txt"),
    eval_case("est-five-columns", TRAJ, "1.0 0 0 0 0\n", "est.txt:1", "expected 8 columns"),
    eval_case("est-words", TRAJ, "one two three four five six seven eight\n", "est.txt:1", "not a number"),
    # --out: a file, a folder of other things
    out_case("is-a-file", {"taken": "a file\n"}, "taken", "run", "exists and is not a folder"),
    out_case("foreign-folder", {"data/notes.txt": "mine\n"}, "data", "run", "not the results of an earlier run"),
    out_case("is-a-file", {"taken": "a file\n"}, "taken", "graph", "exists and is not a folder"),
    out_case("foreign-folder", {"data/notes.txt": "mine\n"}, "data", "graph", "not the results of an earlier run"),
    # maps given to --map-in
    Case("run-map-in-missing", {}, lambda d: ["run", str(BAG), "--out", str(d / "o"), "--map-in", str(d / "m.npz")],
         lambda d: ["m.npz"]),  # fmt: skip
    Case("run-map-in-not-zip", {"m.npz": NOT_A_MAP},
         lambda d: ["run", str(BAG), "--out", str(d / "o"), "--map-in", str(d / "m.npz")], lambda d: ["m.npz"]),
    Case("run-map-in-no-version", {"m.npz": _npz_without_version()},
         lambda d: ["run", str(BAG), "--out", str(d / "o"), "--map-in", str(d / "m.npz")],
         lambda d: ["m.npz", "format_version"]),  # fmt: skip
    Case("graph-map-in-text", {"m.npz": "text\n"},
         lambda d: ["graph", str(BAG), "--out", str(d / "o"), "--map-in", str(d / "m.npz")], lambda d: ["m.npz"]),
    Case("graph-load-map-missing", {},
         lambda d: ["graph", str(BAG), "--out", str(d / "o"), "--load-map", f"{d / 'm.npz'}@3"], lambda d: ["m.npz"]),
    # sources
    Case("run-source-missing", {}, lambda d: ["run", str(d / "nope.mcap"), "--out", str(d / "o")],
         lambda d: ["nope.mcap"]),  # fmt: skip
    Case("run-source-not-mcap", {"x.mcap": "hello\n"}, lambda d: ["run", str(d / "x.mcap"), "--out", str(d / "o")],
         lambda d: ["x.mcap"]),  # fmt: skip
    Case("run-source-truncated", {}, lambda d: ["run", str(d / "cut.mcap"), "--out", str(d / "o")],
         lambda d: ["cut.mcap", "'changing-slam convert --recover FILE.mcap OUT.mcap'"],
         prepare=_cut_bag(BAG.stat().st_size // 3)),  # fmt: skip
    Case("run-bag-malformed-image-strict", {}, lambda d: ["run", str(d / "one_bad.mcap"), "--out", str(d / "o"),
                                                          "--config", "tum_fr1", "--quiet", "--strict"],
         lambda d: ["one_bad.mcap: /camera/rgb/image_color at stamp ", "image data has 10 bytes"],
         prepare=_bad_image_bag),  # fmt: skip
    # convert --recover
    Case("convert-recover-not-mcap", {"x.mcap": "hello\n"},
         lambda d: ["convert", "--recover", str(d / "x.mcap"), str(d / "o.mcap")],
         lambda d: ["x.mcap: not an mcap file"]),  # fmt: skip
    Case("convert-recover-header-only", {}, lambda d: ["convert", "--recover", str(d / "cut.mcap"), str(d / "o.mcap")],
         lambda d: ["cut.mcap: no message could be read", "nothing to recover"], prepare=_cut_bag(40)),
    Case("convert-recover-folder", {"bagdir/metadata.yaml": "storage_identifier: mcap\n"},
         lambda d: ["convert", "--recover", str(d / "bagdir"), str(d / "o.mcap")],
         lambda d: ["bagdir: --recover takes an .mcap file"]),  # fmt: skip
    Case("convert-recover-missing", {}, lambda d: ["convert", "--recover", str(d / "gone.mcap"), str(d / "o.mcap")],
         lambda d: ["gone.mcap: cannot read"]),  # fmt: skip
    Case("graph-source-missing", {}, lambda d: ["graph", str(d / "nope.mcap"), "--out", str(d / "o")],
         lambda d: ["nope.mcap"]),  # fmt: skip
    Case("convert-config-typo", {"bad.yaml": "dataset:\n  depth_scal: 5\n"},
         lambda d: ["convert", str(BAG), str(d / "o.mcap"), "--config", str(d / "bad.yaml")],
         lambda d: ["bad.yaml", "depth_scal"]),  # fmt: skip
    Case("convert-out-parent-is-file", {"taken": "a file\n"},
         lambda d: ["convert", str(BAG), str(d / "taken" / "o.mcap")], lambda d: ["OUT.mcap", "taken"]),
    Case("convert-out-is-folder", {"o.mcap/keep": "x\n"},
         lambda d: ["convert", str(BAG), str(d / "o.mcap")], lambda d: ["o.mcap", "is a folder"]),
    Case("simulate-out-is-file", {"taken": "a file\n"},
         lambda d: ["simulate", "static", "--out", str(d / "taken"), "--frames", "2"],
         lambda d: ["--out", "taken", "not a folder"]),
    Case("simulate-out-parent-is-file", {"taken": "a file\n"},
         lambda d: ["simulate", "static", "--out", str(d / "taken" / "x"), "--frames", "2"],
         lambda d: ["--out", "taken"]),
    # graph options checked before any process starts
    Case("graph-nice", {}, lambda d: ["graph", str(BAG), "--out", str(d / "o"), "--nice", "tracking=99"],
         lambda d: ["--nice tracking=99"]),  # fmt: skip
    Case("graph-nice-node", {}, lambda d: ["graph", str(BAG), "--out", str(d / "o"), "--nice", "trackin=3"],
         lambda d: ["trackin"]),  # fmt: skip
    Case("graph-kill-spec", {}, lambda d: ["graph", str(BAG), "--out", str(d / "o"), "--kill", "tracking@soon"],
         lambda d: ["--kill tracking@soon"]),  # fmt: skip
]


def _write(folder: Path, files: dict[str, str | bytes]) -> None:
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)


def test_the_corpus_has_at_least_40_cases():
    assert len(CASES) >= 40 and len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_ends_with_one_line_naming_what_is_wrong(case: Case, tmp_path: Path, capsys) -> None:
    folder = tmp_path / "case"
    if case.needs_fr1:
        src = Path(FR1_XYZ_10)
        if not src.is_dir():
            pytest.skip(f"{src} missing")
        shutil.copytree(src, folder)
        for name in case.drop:
            (folder / name).unlink()
    folder.mkdir(exist_ok=True)
    _write(folder, case.files)
    if case.prepare is not None:
        case.prepare(folder)
    rc = cli_main(case.argv(folder))
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err, err
    assert rc == 1, (rc, err)
    errors = [ln for ln in lines if ": error: " in ln]
    assert len(errors) == 1 and lines[-1] == errors[0], lines  # one line, nothing after it
    for text in case.expect(folder):
        assert text in errors[0], (text, errors[0])



NODE_CASES = [
    ("bag_player_node", ["rate:=abc"], "parameter rate: expected a number, got 'abc'"),
    ("bag_player_node", ["loop:=maybe"], "parameter loop: expected true or false, got 'maybe'"),
    ("bag_player_node", ["topics:=7"], "parameter topics: expected a list of strings"),
    ("bag_player_node", ["rat:=2.0"], "unknown parameter(s) rat; known:"),
    ("bag_player_node", ["clock_hz:=0.0"], "clock_hz must be > 0"),
    ("local_mapping_node", ["map_cloud_period_s:=soon"], "parameter map_cloud_period_s: expected a number"),
    ("object_map_node", ["config:=no_such_config"], "no_such_config: no such config file"),
]


@pytest.mark.ros
@pytest.mark.parametrize("module,params,expect", NODE_CASES, ids=[f"{m}-{p[0]}" for m, p, _ in NODE_CASES])
def test_bad_node_parameters_end_the_node_with_one_line(module: str, params: list[str], expect: str, capsys,
                                                        monkeypatch) -> None:  # fmt: skip
    import importlib

    pytest.importorskip("rclpy")
    monkeypatch.setenv("ROS_DOMAIN_ID", "171")
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    node = importlib.import_module(f"changing_slam_ros.nodes.{module}")
    argv = [module, *([str(BAG)] if module == "bag_player_node" else []), "--ros-args"]
    for p in params:
        argv += ["-p", p]
    assert node.main(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    errors = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and expect in errors[0], err


def test_a_run_that_tracks_no_frame_says_so_records_it_and_exits_1(tmp_path, capsys):
    import json

    import cv2
    import numpy as np

    src = Path(FR1_XYZ_10)
    if not src.is_dir():
        pytest.skip(f"{src} missing")
    data = tmp_path / "no_depth"
    shutil.copytree(src, data)
    for png in (data / "depth").glob("*.png"):  # no depth reading anywhere: nothing to initialise a map from
        cv2.imwrite(str(png), np.zeros((480, 640), np.uint16))
    rc = cli_main(["run", str(data), "--out", str(tmp_path / "out"), "--config", "tum_fr1", "--quiet", "--no-plot"])
    err = capsys.readouterr().err
    assert rc == 1 and "run: warning: 0 of 9 frames tracked" in err and "Traceback" not in err
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["frames_tracked"] == 0 and metrics["warnings"][0].startswith("0 of 9 frames tracked")


@dataclass(frozen=True)
class WarnCase:
    """Input a run goes on with: it says so in one `run: warning:` line and records it in metrics.json."""

    name: str
    argv: Callable[[Path], list[str]]  # given the case folder; `--out` is `OUT` inside it
    expect: tuple[str, ...]  # substrings of the one warning line
    metrics_key: str  # the metrics.json entry that records it
    needs_fr1: bool = False
    prepare: Callable[[Path], object] | None = None


SIM_BAG = REPO / "bags" / "sim_walking_changing.mcap"
FR1_ARGS = ["--config", "tum_fr1", "--max-frames", "2"]
SEVEN_SCENES_K = "585, 0, 320, 0, 585, 240, 0, 0, 1"
WARN_CASES = [
    WarnCase("tum-intrinsics-txt-disagrees", lambda d: ["run", str(d / "data"), *FR1_ARGS],
             ("camera of ", "tum_fr1.yaml disagrees with ", "camera-intrinsics.txt: fx 517.3 vs 585, fy 516.5 vs 585",
              "using the camera of "), "camera_mismatch", needs_fr1=True,
             prepare=lambda d: (d / "data" / "camera-intrinsics.txt").write_text("585 0 320\n0 585 240\n0 0 1\n")),
    WarnCase("tum-camera-info-yaml-disagrees", lambda d: ["run", str(d / "data"), *FR1_ARGS],
             ("camera_info.yaml: fx 517.3 vs 585", "using camera_info.yaml"), "camera_mismatch", needs_fr1=True,
             prepare=lambda d: (d / "data" / "camera_info.yaml").write_text(CAMERA_INFO_YAML % SEVEN_SCENES_K)),
    WarnCase("bag-camera-info-disagrees",
             lambda d: ["run", str(SIM_BAG), "--config", "7scenes", "--max-frames", "2", "--no-dynamic"],
             ("7scenes.yaml disagrees with the CameraInfo on /camera/rgb/camera_info of ", "fx 292.5 vs 262.5",
              "640x480 values scaled to 320x240", "using the CameraInfo"), "camera_mismatch"),
    WarnCase("bag-malformed-image", lambda d: ["run", str(d / "one_bad.mcap"), "--config", "tum_fr1", "--no-loop"],
             ("skipped a malformed message on /camera/rgb/image_color at stamp ", "image data has 10 bytes"),
             "skipped_messages", prepare=_bad_image_bag),
]  # fmt: skip


@pytest.mark.parametrize("case", WARN_CASES, ids=[c.name for c in WARN_CASES])
def test_input_a_run_goes_on_with_is_said_once_and_recorded(case: WarnCase, tmp_path: Path, capsys) -> None:
    import json

    folder = tmp_path / "case"
    folder.mkdir()
    if case.needs_fr1:
        src = Path(FR1_XYZ_10)
        if not src.is_dir():
            pytest.skip(f"{src} missing")
        shutil.copytree(src, folder / "data")
    if case.prepare is not None:
        case.prepare(folder)
    rc = cli_main([*case.argv(folder), "--out", str(folder / "OUT"), "--quiet", "--no-plot"])
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err, err
    said = [ln for ln in err.splitlines() if ln.startswith("run: warning: ") and all(t in ln for t in case.expect)]
    assert len(said) == 1, err
    metrics = json.loads((folder / "OUT" / "metrics.json").read_text())
    assert metrics[case.metrics_key], metrics[case.metrics_key]
    if case.metrics_key == "camera_mismatch":
        assert said[0].removeprefix("run: warning: ") in metrics["warnings"]
