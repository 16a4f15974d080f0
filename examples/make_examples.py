"""Regenerate the example files from the imported CMU corpus (test subject 07, a walk).

    python examples/make_examples.py data/cmu_amass

walk.npz        clean motion (imported by `mdvae import`, 30 Hz, SMPL-H layout, built-in body)
noisy_walk.npz  the same with Pose-NDF noise, sigma = 0.15 rad, seed 0 (`mdvae add-noise`)
Motion derived from the CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu).
"""

from __future__ import annotations

import sys
from pathlib import Path

from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.motion.noise import add_pose_noise, file_rng

HERE = Path(__file__).resolve().parent


def main() -> None:
    corpus = Path(sys.argv[1] if len(sys.argv) > 1 else "data/cmu_amass")
    clean = load_motion(corpus / "asfamc" / "07" / "07_01.npz")
    save_motion(clean, HERE / "walk.npz")
    noisy = add_pose_noise(clean, 0.15, file_rng(0, Path("walk.npz")))
    save_motion(noisy, HERE / "noisy_walk.npz")
    print(f"walk.npz and noisy_walk.npz: {clean.num_frames} frames at {clean.fps:g} Hz")


if __name__ == "__main__":
    main()
