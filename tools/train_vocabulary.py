#!/usr/bin/env python3
"""Train the shipped ORB bag-of-words vocabulary (changing_slam_ros/models/orb_vocabulary.npz).

Training images are ONLY ones we may redistribute a model derived from:
- the 10 colour frames of TUM RGB-D freiburg1_xyz in ../shared/data/tum_fr1_xyz_first10 (CC BY 4.0, TUM CVG);
- scikit-image's bundled sample photographs listed in SKIMAGE_IMAGES with the licence their docstrings state.
Each image is augmented (rotations, scales, crops, a brightness change) to get enough descriptors. ORB
descriptors come from the project's extractor (`core.orb_features.OrbExtractor`, default `FeatureConfig`), so
the words match what SLAM quantises; `--extractor opencv` uses plain cv2.ORB instead.
Deterministic: same inputs and seed give the same file.

    .venv/bin/python tools/train_vocabulary.py --out changing_slam_ros/models/orb_vocabulary.npz
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.features.vocabulary import train_vocabulary  # noqa: E402
from changing_slam_ros.io.atomic import atomic_write_bytes  # noqa: E402

# name -> licence as stated in the skimage.data docstring (scikit-image 0.26)
SKIMAGE_IMAGES = {
    "astronaut": "public domain (NASA)",
    "brick": "CC0 (CC0Textures)",
    "camera": "CC0 (Lav Varshney)",
    "chelsea": "CC0 (Stefan van der Walt)",
    "coffee": "CC0 (Rachel Michetti)",
    "coins": "no known copyright restrictions (Brooklyn Museum)",
    "grass": "CC0 (DeviantArt linolafett)",
    "gravel": "CC0 (CC0Textures)",
    "hubble_deep_field": "public domain (NASA)",
    "immunohistochemistry": "no known copyright restrictions (CMMI)",
    "rocket": "public domain (SpaceX)",
    "text": "public domain (Wikipedia)",
    "retina": "CC0 (Mikael Haggstrom)",
    "clock": "public domain (Stefan van der Walt)",
    "cell": "CC0 (Paul Mueller et al.)",
}
DEFAULT_FR1 = REPO.parent / "shared" / "data" / "tum_fr1_xyz_first10" / "rgb"


def load_images(fr1_dir: Path) -> list[tuple[str, np.ndarray]]:
    """Grey uint8 training images, in a fixed order."""
    import skimage.data

    images: list[tuple[str, np.ndarray]] = []
    for path in sorted(fr1_dir.glob("*.png")):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise SystemExit(f"{path}: cannot read image")
        images.append((f"tum_fr1_xyz/{path.name}", grey))
    if not images:
        raise SystemExit(f"{fr1_dir}: no PNG frames found")
    for name in SKIMAGE_IMAGES:
        img = np.asarray(getattr(skimage.data, name)())
        if img.ndim == 3:
            img = cv2.cvtColor(img[..., :3].astype(np.uint8), cv2.COLOR_RGB2GRAY)
        images.append((f"skimage/{name}", img.astype(np.uint8)))
    return images


def augmentations(grey: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """The original plus rotated, scaled, cropped and re-lit copies (fixed by rng)."""
    h, w = grey.shape
    out = [grey]
    for angle in (-30.0, -12.0, 15.0, 35.0):
        m = cv2.getRotationMatrix2D((w / 2, h / 2), angle, 1.0)
        out.append(cv2.warpAffine(grey, m, (w, h), borderMode=cv2.BORDER_REFLECT))
    for scale in (0.6, 1.5):
        out.append(cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA))
    for _ in range(2):
        cw, ch = int(w * 0.6), int(h * 0.6)
        x0, y0 = int(rng.integers(0, w - cw + 1)), int(rng.integers(0, h - ch + 1))
        crop = grey[y0 : y0 + ch, x0 : x0 + cw]
        out.append(cv2.resize(crop, (w, h), interpolation=cv2.INTER_LINEAR))
    gain = np.clip(grey.astype(np.float32) * 0.7 + 20.0, 0, 255).astype(np.uint8)
    out.append(cv2.GaussianBlur(gain, (3, 3), 0.8))
    return out


def describe(grey: np.ndarray, n_features: int) -> np.ndarray:
    """Descriptors as SLAM computes them: the project's grid-bucketed ORB extractor (no distortion, no depth)."""
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.core.features.orb_features import FeatureConfig, OrbExtractor

    h, w = grey.shape
    camera = CameraIntrinsics(w, h, 500.0, 500.0, w / 2, h / 2)
    features = OrbExtractor(FeatureConfig(n_features=n_features), camera).extract(grey, np.zeros((h, w), np.float32))
    return features.descriptors


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=REPO / "changing_slam_ros" / "models" / "orb_vocabulary.npz")
    ap.add_argument("--fr1", type=Path, default=DEFAULT_FR1, help="folder of TUM fr1_xyz colour PNGs")
    ap.add_argument("--branching", type=int, default=10)
    ap.add_argument("--depth", type=int, default=5)
    ap.add_argument("--features", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--extractor", choices=("project", "opencv"), default="project",
                    help="project: core.orb_features.OrbExtractor with default FeatureConfig (what SLAM uses); "
                         "opencv: plain cv2.ORB with FAST threshold 20")
    args = ap.parse_args(argv)

    cv2.setRNGSeed(args.seed)
    rng = np.random.default_rng(args.seed)
    orb = cv2.ORB_create(nfeatures=args.features, scaleFactor=1.2, nlevels=8, edgeThreshold=19,
                         fastThreshold=20, patchSize=31)
    per_image: list[np.ndarray] = []
    t0 = time.perf_counter()
    for name, grey in load_images(args.fr1):
        for aug in augmentations(grey, rng):
            desc = describe(aug, args.features) if args.extractor == "project" else orb.detectAndCompute(aug, None)[1]
            if desc is not None and len(desc):
                per_image.append(desc.astype(np.uint8))
        print(f"{name}: {grey.shape[1]}x{grey.shape[0]}", file=sys.stderr)
    n_desc = sum(len(d) for d in per_image)
    print(f"{len(per_image)} augmented images, {n_desc} descriptors ({time.perf_counter() - t0:.1f} s)",
          file=sys.stderr)
    t1 = time.perf_counter()
    vocab = train_vocabulary(per_image, branching=args.branching, depth=args.depth, seed=args.seed)
    print(f"trained {vocab.num_words} words, {vocab.num_nodes} nodes in {time.perf_counter() - t1:.1f} s",
          file=sys.stderr)
    buf = io.BytesIO()
    np.savez_compressed(buf, **vocab.to_arrays())
    atomic_write_bytes(args.out, buf.getvalue())
    print(f"wrote {args.out} ({len(buf.getvalue()) / 1e6:.2f} MB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
