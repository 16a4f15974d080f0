"""How well can the prior's decoder represent held-out motion at all?

Encodes held-out windows (posterior means, as `benchmarks/prior.py` does), then optimises the
latents z_1..z_T of every window directly (Adam, decoder frozen, the true x0) to fit the window's
mesh. The V2V before is the encoder's reconstruction; the V2V after bounds what any encoder could
reach with this decoder (the latents are not held to the prior here). A large gap means the
reconstruction error is the encoder's (amortised inference), not the decoder's capacity.

    python benchmarks/decoder_floor.py [--prior PATH] [--steps 150] [--every 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.state import state_to_params

try:
    from benchmarks import common
except ModuleNotFoundError:  # run as a file: python benchmarks/<name>.py
    import common  # type: ignore[no-redef]


def mesh(body: BodyModel, x: torch.Tensor, betas: torch.Tensor, ids: torch.Tensor):
    """Vertices (subset) and their root-relative version.  x: (B, T, 138) -> 2 x (B*T, K, 3)"""
    B, T = x.shape[:2]
    q = state_to_params(x.reshape(B * T, -1))
    out = body(q.root_orient, q.pose_body, q.trans, betas.repeat_interleave(T, 0), vertex_ids=ids)
    return out.vertices, out.vertices - out.joints[:, :1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prior", default=None, help="prior checkpoint/run (default: shipped)")
    ap.add_argument("--corpus", default="data/corpus")
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-files", type=int, default=34)
    ap.add_argument("--every", type=int, default=2, help="keep every n-th window")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--lr", type=float, default=0.02)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    start = time.time()
    prior, _, body, _, w = common.prior_and_windows(
        args.prior, Path(args.corpus), args.split, args.max_files
    )
    w = w.subset(torch.arange(0, len(w), args.every))
    norm = prior.normalizer
    xn, x0n = norm.normalize(w.x), norm.normalize(w.x0)
    ids = torch.arange(0, body.v_template.shape[0], 27)  # ~256 vertices spread over the mesh
    with torch.no_grad():
        x_mean, z, _, _ = prior.dvae.encode_decode(xn, x0n, sample=False)
        gt_abs, gt_rel = mesh(body, w.x, w.betas, ids)
        enc_abs, enc_rel = mesh(body, norm.denormalize(x_mean), w.betas, ids)
    z = z.clone().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=args.lr)
    for _ in range(args.steps):
        x_mean, _ = prior.dvae.decoder(z, x0n)
        v_abs, v_rel = mesh(body, norm.denormalize(x_mean), w.betas, ids)
        rel = (v_rel - gt_rel).norm(dim=-1).mean()
        absolute = (v_abs - gt_abs).norm(dim=-1).mean()
        opt.zero_grad()
        (rel + absolute).backward()
        opt.step()
    cm = lambda a, b: 100 * float((a - b).norm(dim=-1).mean())  # noqa: E731
    print(
        f"Decoder floor on the {args.split} split: {len(w)} windows of 60 frames, "
        f"{args.steps} Adam steps on z ({time.time() - start:.0f} s)\n"
    )
    print("| latents | V2V root-relative (cm) | V2V absolute (cm) |")
    print("|---|---|---|")
    print(f"| encoder's posterior means | {cm(enc_rel, gt_rel):.2f} | {cm(enc_abs, gt_abs):.2f} |")
    print(f"| optimised per window | {100 * rel.item():.2f} | {100 * absolute.item():.2f} |")


if __name__ == "__main__":
    main()
