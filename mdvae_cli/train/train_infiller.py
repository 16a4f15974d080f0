"""Train the learned fill (``model.infiller``) on clean motion with holes cut at random.

Windows of the corpus's ``train`` split (30 Hz) get one hole each (every joint for 5-60
frames, or one limb for 15-60), filled with the cubic Hermite curve; every step fits the
corrections that take the curve to the motion on a batch of a pool of such windows, and
draws a few of the pool anew (a window's hole costs more to make than to learn from). The
``val`` split's windows (drawn once, seeded) pick the best checkpoint.

    python -m mdvae_cli.train.train_infiller data/corpus -o runs/infiller --steps 3000 --seed 0
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.model.checkpoint import save_checkpoint
from mdvae_cli.model.infiller import (
    LONGEST_HOLE,
    Infiller,
    InfillerConfig,
    canonical,
    features,
    infill_loss,
    target_corrections,
)
from mdvae_cli.motion.holes import LIMBS, hermite_fill_rows
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.train.corpus import select_files

FRAME_HOLE_SHARE = 0.65
CONTEXT = 10  # fewest observed frames each side of a training hole
#: jitter on a window before its curve is fitted, drawn per window up to this (rad): the fill
#: reads a denoised result, a little off the motion
NOISE_RAD = 0.03
POOL = 2048  # windows held at once ...
REFRESH = 8  # ... of which this many are drawn anew every step


def load_takes(corpus: Path, split: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rotations (T, 22, 3), translation (T, 3)) of every file of a split, at 30 Hz."""
    out = []
    for f in select_files([corpus], corpus / "split.json", split):
        m = resample_motion(load_motion(f), 30.0)
        rot = np.concatenate([m.root_orient[:, None], m.pose_body], axis=1)
        out.append((rot.astype(np.float64), np.asarray(m.trans, np.float64)))
    return out


def draw_windows(takes, count: int, length: int, rng: np.random.Generator):
    """``count`` windows with one hole each, as tensors: (rot_fill, trans_fill, rot_true,
    trans_true, mask, place, hole_length) with shapes (B, L, 22, 3), (B, L, 3), the same
    twice, (B, L, 22), (B, L), (B, L)."""
    long_enough = [t for t in takes if len(t[0]) >= length]
    weights = np.array([len(t[0]) - length + 1 for t in long_enough], float)
    picks = rng.choice(len(long_enough), size=count, p=weights / weights.sum())
    cols = {k: [] for k in ("rf", "tf", "rt", "tt", "mask", "place", "len")}
    for k in picks:
        rot, trans = long_enough[k]
        s = int(rng.integers(len(rot) - length + 1))
        r, t = rot[s : s + length], trans[s : s + length]
        if rng.random() < FRAME_HOLE_SHARE:
            n, joints = int(rng.integers(5, LONGEST_HOLE + 1)), list(range(22))
        else:
            n = int(rng.integers(15, LONGEST_HOLE + 1))
            joints = list(LIMBS[list(LIMBS)[rng.integers(len(LIMBS))]])
        a = int(rng.integers(CONTEXT, length - CONTEXT - n + 1))
        frames = np.ones(length, bool)
        frames[a : a + n] = False
        noisy_r = r + rng.normal(0.0, rng.uniform(0.0, NOISE_RAD), r.shape)
        rf, tf = hermite_fill_rows(noisy_r, t, frames, joints)
        mask = np.ones((length, 22))
        mask[a : a + n, joints] = 0.0
        place = np.zeros(length)
        place[a : a + n] = (np.arange(n) + 1) / (n + 1)
        hole = np.zeros(length)
        hole[a : a + n] = n / LONGEST_HOLE
        for key, v in zip(cols, (rf, tf, r, t, mask, place, hole), strict=True):
            cols[key].append(v)
    return tuple(torch.as_tensor(np.stack(v)) for v in cols.values())


def batch_loss(model: Infiller, batch) -> torch.Tensor:
    rf, tf, rt, tt, mask, place, hole = batch
    rf_c, tf_c, yaw = canonical(rf, tf)
    # the truth in the same frame (the window's first frame is observed: same yaw)
    rt_c, tt_c, _ = canonical(
        torch.cat([rf[:, :1], rt[:, 1:]], 1), torch.cat([tf[:, :1], tt[:, 1:]], 1)
    )
    target = target_corrections(rf_c, tf_c, rt_c, tt_c).float()
    pred = model(features(rf_c, tf_c, mask, place, hole))
    return infill_loss(pred, target, mask.float())


def train(
    corpus: Path, out: Path, steps: int, seed: int, batch: int, lr: float, channels: int, log
) -> dict:
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    cfg = InfillerConfig(channels=channels)
    model = Infiller(cfg)
    train_takes, val_takes = load_takes(corpus, "train"), load_takes(corpus, "val")
    val = draw_windows(val_takes, 256, cfg.window, np.random.default_rng(seed + 1))
    pool = list(draw_windows(train_takes, POOL, cfg.window, rng))
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.05)
    best, history, start = float("inf"), [], time.time()
    command = (f"python -m mdvae_cli.train.train_infiller {corpus} -o {out} --steps {steps} "
               f"--seed {seed} --batch {batch} --lr {lr} --channels {channels}")  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    for step in range(1, steps + 1):
        model.train()
        pick = torch.as_tensor(rng.choice(POOL, size=batch, replace=False))
        loss = batch_loss(model, tuple(v[pick] for v in pool))
        fresh = torch.as_tensor(rng.choice(POOL, size=REFRESH, replace=False))
        for v, new in zip(pool, draw_windows(train_takes, REFRESH, cfg.window, rng), strict=True):
            v[fresh] = new
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % 100 == 0 or step == steps:
            model.eval()
            with torch.no_grad():
                v = float(batch_loss(model, val))
            history.append({"step": step, "train": float(loss), "val": v, "s": time.time() - start})
            log(json.dumps(history[-1]))
            meta = {"kind": "infiller", "config": cfg.to_dict(), "step": step, "val": v,
                    "seed": seed, "steps": steps, "batch": batch, "lr": lr,
                    "command": command}  # fmt: skip
            if v < best:
                best = v
                save_checkpoint(out / "best.npz", model.state_dict(), meta)
            save_checkpoint(out / "last.npz", model.state_dict(), meta)
    (out / "log.json").write_text(json.dumps(history, indent=1) + "\n")
    return {"best_val": best, "steps": steps}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--channels", type=int, default=96)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(
        train(
            args.corpus, args.out, args.steps, args.seed, args.batch, args.lr, args.channels, print
        )
    )


if __name__ == "__main__":
    main()
