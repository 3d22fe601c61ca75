"""Regenerate `evo_reference.json` by running the evo command-line tools (never imported here).

evo is GPL, so the project never depends on it. Run this by hand in a throwaway venv:

    python3 -m venv /tmp/evo-venv && /tmp/evo-venv/bin/pip install evo==1.31.0
    PATH=/tmp/evo-venv/bin:$PATH /tmp/evo-venv/bin/python test/eval/generate_evo_reference.py

It runs `evo_ape` / `evo_rpe` on the TUM reference trajectories, reads the statistics from the
`--save_results` zip, and writes the command lines and figures to `test/eval/evo_reference.json`.
"""

from __future__ import annotations

import importlib.metadata
import io
import json
import shlex
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA_REL = "../shared/data/tum_reference_trajectories"  # relative to the repository root
DATA = (HERE.parents[1] / DATA_REL).resolve()

FR1_GT = "freiburg1_xyz-groundtruth.txt"
FR2_GT = "fr2_desk_groundtruth.txt"
PAIRS = [
    (FR1_GT, "freiburg1_xyz-rgbdslam.txt", False),
    (FR1_GT, "freiburg1_xyz-rgbdslam_drift.txt", False),
    (FR1_GT, "freiburg1_xyz-rgbdslam_drift_short.txt", False),
    (FR1_GT, "freiburg1_xyz-ORB_kf_mono.txt", True),
    (FR2_GT, "fr2_desk_ORB.txt", False),
    (FR2_GT, "fr2_desk_ORB_kf_mono.txt", True),
]
MAX_DIFFS = [0.02, 0.01, 0.05]


def run_evo(tool: str, args: list[str]) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as tmp:
        zip_path = Path(tmp) / "res.zip"
        cmd = [tool, "tum", *args, "--no_warnings", "--silent", "--save_results", str(zip_path)]
        subprocess.run(cmd, cwd=DATA, check=True, capture_output=True)
        with zipfile.ZipFile(zip_path) as zf:
            stats = json.loads(zf.read("stats.json"))
            errors = np.load(io.BytesIO(zf.read("error_array.npy")))
    shown = [tool, "tum", *args]
    return {
        "command": " ".join(shlex.quote(a) for a in shown),
        "stats": {k: float(v) for k, v in stats.items()},
        "count": int(len(errors)),
    }


def main() -> int:
    version = importlib.metadata.version("evo")  # package metadata only; evo is not imported
    ape_rows: list[dict[str, object]] = []
    rpe_rows: list[dict[str, object]] = []
    for gt, est, mono in PAIRS:
        for d in MAX_DIFFS:
            for align in (["-a"], ["-as"]):
                row = run_evo("evo_ape", [gt, est, *align, "--t_max_diff", str(d)])
                row.update(gt=gt, est=est, max_diff_s=d, offset_s=0.0, sim3=align == ["-as"],
                           monocular=mono)
                ape_rows.append(row)
        for offset in (0.005, -0.012):
            row = run_evo("evo_ape", [gt, est, "-a", "--t_max_diff", "0.02", "--t_offset", str(offset)])
            row.update(gt=gt, est=est, max_diff_s=0.02, offset_s=offset, sim3=False, monocular=mono)
            ape_rows.append(row)
        if est.endswith(("_short.txt", "_kf_mono.txt")):
            # Roles swapped so that the estimate is the longer trajectory: evo then searches the
            # other way round and applies the offset to the estimate's stamps.
            for offset in (0.0, 0.005):
                row = run_evo("evo_ape", [est, gt, "-a", "--t_max_diff", "0.02", "--t_offset", str(offset)])
                row.update(gt=est, est=gt, max_diff_s=0.02, offset_s=offset, sim3=False,
                           monocular=mono, swapped=True)
                ape_rows.append(row)
        aligns = (["-a"], ["-as"]) if mono else (["-a"],)
        for align in aligns:
            for delta, all_pairs in ((1, False), (10, False), (10, True)):
                for relation, key in (("trans_part", "translation_m"), ("angle_deg", "rotation_deg")):
                    extra = ["--all_pairs"] if all_pairs else []
                    row = run_evo(
                        "evo_rpe",
                        [gt, est, *align, "-r", relation, "-d", str(delta), "-u", "f", *extra,
                         "--t_max_diff", "0.02"],
                    )
                    row.update(gt=gt, est=est, max_diff_s=0.02, offset_s=0.0, delta_frames=delta,
                               all_pairs=all_pairs, relation=key, sim3=align == ["-as"],
                               monocular=mono)
                    rpe_rows.append(row)
        print(f"done {est}", file=sys.stderr)
    # The fr2_desk ground truth against itself: it holds one duplicated stamp, and evo pairs
    # both poses of that stamp with the first one, so the errors are not all zero.
    for tool, extra in (("evo_ape", []), ("evo_rpe", ["-r", "trans_part"]), ("evo_rpe", ["-r", "angle_deg"])):
        # "./" because evo cannot save the results of two trajectories with the same name.
        row = run_evo(tool, [FR2_GT, "./" + FR2_GT, "-a", *extra, "--t_max_diff", "0.02"])
        row.update(gt=FR2_GT, est=FR2_GT, max_diff_s=0.02, offset_s=0.0, sim3=False, monocular=False,
                   self_comparison=True)
        if tool == "evo_ape":
            ape_rows.append(row)
        else:
            row.update(delta_frames=1, all_pairs=False,
                       relation="translation_m" if "trans_part" in extra else "rotation_deg")
            rpe_rows.append(row)
    out = {
        "generated_by": "test/eval/generate_evo_reference.py (evo run as a command-line tool)",
        "evo_version": version,
        "numpy_version": np.__version__,
        "data_dir": DATA_REL,
        "note": "commands were run with the data folder as working directory; "
                "--no_warnings --silent --save_results were added to read the figures",
        "ape": ape_rows,
        "rpe": rpe_rows,
    }
    (HERE / "evo_reference.json").write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
