"""Train the marking-point verifier (a second look at each candidate); export ONNX.

Stages, each re-runnable:

1. mine: simulated top views of worlds the marking-point CNN never trained on; the
   float grid pair (``FLOAT_MODELS``, ``verify=False``) at ``CANDIDATE_THRESHOLD``; each
   candidate is positive when a visible labelled point lies within ``REFINE_PX`` of it
   that no stronger candidate took (:func:`assign_nearby`), with the move and turn onto
   that point as targets (:func:`refinement_target`); candidates near a covered label and
   with none to take are left out; also the ps2.0 hit label (10 px, 30 deg) as found, for
   the evaluation; the turned patches of
   :func:`semslam.perception.point_verifier.crop_point_patches` cached as ``.npz`` shards
   in ``--cache`` (training sets: a second patch per candidate, the point moved by up to
   3 px and turned by up to 8 deg, as the grid errs);
2. train: a small CNN on ``--threads`` CPU threads for at most ``--minutes``: binary
   cross-entropy, plus on the positives the move and the turn (:func:`_loss`);
   photometric augmentation and left-right mirrors (a mirrored T or L junction is one);
   fixed seeds; two options the shipped model does not use (tried, not kept:
   ``BENCHMARKS.md``): ``--scene-augment`` (paving joints, hard shadows, stitching seams)
   and ``--line-end-negatives`` (positives with their entrance bar painted out, as
   negatives);
3. export: ONNX (opset 17, input ``(N, 64, 64, 3)`` uint8 BGR, output ``(N, 5)`` float32:
   probability, move right and up, the turn's cosine and sine), written atomically,
   checked against torch;
4. evaluate: on held-out worlds, the ps2.0 point precision and recall of the pair alone
   (at its threshold) and of the candidates rescored by the verifier, each way of
   combining the two scores, with and without the move and turn; each way's threshold is
   chosen on the validation worlds (100-149) and reported on the test worlds (0-99).

Example (the shipped file; ``models/point_verifier.md``)::

    PYTHONPATH=. python tools/train_point_verifier.py --stage mine
    PYTHONPATH=. python tools/train_point_verifier.py --stage train --minutes 45 \
        --out semslam/models/point_verifier.onnx
    PYTHONPATH=. python tools/train_point_verifier.py --stage evaluate \
        --out semslam/models/point_verifier.onnx

The second shipped file (``models/point_verifier_turned.md``) is the same recipe with
``--wide-turn-deg 45`` at both stages (a third patch per training candidate, turned by up to
45 deg, as the grid turns some real candidates) and ``--minutes 40``.

``--init-onnx`` fine-tunes an exported file (its batch norms frozen: ``onnx_weights.py``);
the set ``cross`` holds worlds whose T junctions' separators cross the entrance line.

torch is needed here only; the package runs the exported model with onnxruntime.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

CANDIDATE_THRESHOLD = 0.2  # the grid's confidence above which a cell is a candidate
SETS = {  # name: (world seeds, views per world, sampling seed, jittered copies)
    "train": (range(2000, 2800), 6, 5001, True),
    "train2": (range(2800, 4000), 6, 6001, True),
    "val": (range(100, 150), 5, 777, False),
    "test": (range(0, 100), 5, 20261122, False),  # bench_perception.py's views
    # every T junction's separator painted across the entrance line ("+", "X"), as in many
    # of the real ps2.0 garages (PaintVariation.cross_share); not in the shipped file's sets
    "cross": (range(4000, 4400), 6, 8001, True),
}
CROSSED = {"cross"}  # the sets whose worlds are painted so
REFINE_PX = 20.0  # a labelled point this near a candidate is the one it should move to
CHUNK = 20  # worlds per training shard; an evaluation set is one shard, so that its views
# are the same as a single ``sample_topviews`` call's (the test set: bench_perception.py's)


# ----------------------------------------------------------------------------- mining


def _mine_shard(job: tuple[str, list[int], int, int, bool, float, str]) -> str:
    from semslam.evaluation.detection_metrics import match_points
    from semslam.perception.marking_points import FLOAT_MODELS, MarkingPointDetector
    from semslam.perception.onnx_model import model_path
    from semslam.perception.point_verifier import crop_point_patches
    from semslam.simulation.topview_samples import PaintVariation, sample_topviews

    name, seeds, per_world, seed, jitter, wide_turn_deg, path = job
    paint = (PaintVariation(thin_share=0.0, stub_share=0.0, cross_share=1.0)
             if name in CROSSED else None)
    if os.path.exists(path):
        return path
    # the float pair the verifier was trained behind (the 8-bit twins came later)
    detector = MarkingPointDetector(
        [model_path(f) for f in FLOAT_MODELS], threshold=CANDIDATE_THRESHOLD, verify=False,
        check_entrance=False,  # every candidate the grid offers, as at run time
    )
    rng = np.random.default_rng(seed + 17)
    cols: dict[str, list] = {k: [] for k in
                             ("patches", "y", "y_near", "target", "conf", "view", "uv",
                              "dir", "copy")}
    lab: dict[str, list] = {k: [] for k in ("lpts", "ldir", "locc", "lcount")}
    for view, s in enumerate(sample_topviews(seeds, per_world, seed, paint=paint)):
        a = s.annotation
        pts = detector.detect(s.image)
        uv = np.array([p.uv for p in pts], float).reshape(-1, 2)
        dirs = np.array([p.direction for p in pts], float)
        conf = np.array([p.confidence for p in pts], float)
        lpts = np.asarray(a.points, float).reshape(-1, 2)
        ldir = np.asarray(a.directions, float).reshape(-1)
        locc = np.asarray(a.occluded, bool).reshape(-1)
        lab["lpts"].append(lpts)
        lab["ldir"].append(ldir)
        lab["locc"].append(locc)
        lab["lcount"].append(len(lpts))
        if not len(uv):
            continue
        y = np.zeros(len(uv), np.int8)
        match = match_points(uv, dirs, conf, lpts[~locc], ldir[~locc])
        y[match >= 0] = 1
        near_label = assign_nearby(uv, conf, lpts[~locc])
        y_near = (near_label >= 0).astype(np.int8)
        covered = lpts[locc]
        if len(covered):
            near = np.linalg.norm(uv[:, None] - covered[None], axis=2).min(axis=1) <= 10.0
            y[near & (match < 0)] = -1  # a covered label: neither hit nor false
            near = np.linalg.norm(uv[:, None] - covered[None], axis=2).min(axis=1) <= REFINE_PX
            y_near[near & (near_label < 0)] = -1
        copies = [(uv, dirs)]
        if jitter:
            shift = np.clip(rng.normal(0.0, 1.5, uv.shape), -3, 3)
            turn = np.clip(rng.normal(0.0, math.radians(4), len(dirs)), -0.14, 0.14)
            copies.append((uv + shift, dirs + turn))
            if wide_turn_deg > 0:  # as the grid turns some real candidates, 15-40 deg off
                wide = rng.uniform(-1.0, 1.0, len(dirs)) * math.radians(wide_turn_deg)
                copies.append((uv + shift, dirs + wide))
        target_pts = lpts[~locc][np.maximum(near_label, 0)] if (~locc).any() else uv
        target_dir = ldir[~locc][np.maximum(near_label, 0)] if (~locc).any() else dirs
        for c, (u, d) in enumerate(copies):
            cols["patches"].append(crop_point_patches(s.image, u, d))
            cols["target"].append(refinement_target(u, d, target_pts, target_dir))
            cols["y_near"].append(y_near)
            cols["y"].append(y)
            cols["conf"].append(conf)
            cols["view"].append(np.full(len(uv), view, np.int32))
            cols["uv"].append(uv)
            cols["dir"].append(dirs)
            cols["copy"].append(np.full(len(uv), c, np.int8))
    out = {k: np.concatenate(v) for k, v in cols.items()}
    out["lpts"] = np.concatenate(lab["lpts"])
    out["ldir"] = np.concatenate(lab["ldir"])
    out["locc"] = np.concatenate(lab["locc"])
    out["lcount"] = np.asarray(lab["lcount"], np.int32)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **out)
    os.replace(tmp, path)
    print(f"  {name} shard {Path(path).name}: {len(out['y'])} patches", flush=True)
    return path


def assign_nearby(uv: np.ndarray, conf: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """For each candidate the index of the labelled point it should move to, or -1: greedy
    one-to-one by decreasing confidence, the nearest free label within ``REFINE_PX`` in any
    direction."""
    out = np.full(len(uv), -1, int)
    if not len(uv) or not len(labels):
        return out
    d = np.linalg.norm(uv[:, None] - labels[None], axis=2)
    free = np.ones(len(labels), bool)
    for i in np.argsort(-conf, kind="stable"):
        j = np.nonzero(free & (d[i] <= REFINE_PX))[0]
        if len(j):
            out[i] = j[np.argmin(d[i, j])]
            free[out[i]] = False
    return out


def refinement_target(uv: np.ndarray, dirs: np.ndarray, to_uv: np.ndarray,
                      to_dirs: np.ndarray) -> np.ndarray:
    """(N, 4) float32: the move to ``to_uv`` along the patch's right and up, in top-view
    pixels, and the cosine and sine of the turn to ``to_dirs`` (positive: towards the
    patch's right); see :func:`semslam.perception.point_verifier.refined`."""
    dx, dy = np.cos(dirs), np.sin(dirs)
    move = to_uv - uv
    along_right = move[:, 0] * -dy + move[:, 1] * dx
    along_up = move[:, 0] * dx + move[:, 1] * dy
    turn = to_dirs - dirs
    return np.stack([along_right, along_up, np.cos(turn), np.sin(turn)], 1).astype(np.float32)


def _jobs(name: str, cache: Path, wide_turn_deg: float = 0.0) -> list[tuple]:
    worlds, per_world, seed, jitter = SETS[name]
    worlds = list(worlds)
    chunk = CHUNK if jitter else len(worlds)
    wide = wide_turn_deg if jitter else 0.0
    tag = f"_wide{wide:g}" if wide > 0 else ""
    return [
        (name, worlds[k : k + chunk], per_world, seed + k, jitter, wide,
         str(cache / f"pv_{name}_{seed}_{per_world}_{worlds[k]:05d}_{chunk}{tag}.npz"))
        for k in range(0, len(worlds), chunk)
    ]


def mine(names: list[str], cache: Path, workers: int, wide_turn_deg: float = 0.0) -> None:
    cache.mkdir(parents=True, exist_ok=True)
    jobs = [job for name in names for job in _jobs(name, cache, wide_turn_deg)]
    t0 = time.time()
    with mp.get_context("spawn").Pool(workers) as pool:
        for n, _ in enumerate(pool.imap_unordered(_mine_shard, jobs), 1):
            print(f"mined {n}/{len(jobs)} shards {time.time() - t0:.0f} s", flush=True)


def load(name: str, cache: Path, wide_turn_deg: float = 0.0) -> dict[str, np.ndarray]:
    """A mined set; views renumbered across shards."""
    parts = [np.load(job[-1]) for job in _jobs(name, cache, wide_turn_deg)]
    out: dict[str, list] = {k: [] for k in parts[0].files}
    views = 0
    for p in parts:
        for k in p.files:
            out[k].append(p[k] + views if k == "view" else p[k])
        views += len(p["lcount"])
    return {k: np.concatenate(v) for k, v in out.items()}


# ----------------------------------------------------------------------------- model


MOVE_SCALE = 10.0  # px: the network's move outputs are in these units


def build_model():
    """Outputs per patch: the logit that a labelled point lies within ``REFINE_PX``, the
    move to it along the patch's right and up (``MOVE_SCALE`` px units), and the turn to
    its direction (cosine, sine; normalised in the export)."""
    import torch.nn as nn

    def block(i: int, o: int) -> list:
        return [nn.Conv2d(i, o, 3, 1, 1, bias=False), nn.BatchNorm2d(o), nn.ReLU()]

    return nn.Sequential(
        *block(3, 16), nn.MaxPool2d(2),  # 32 x 32
        *block(16, 24), nn.MaxPool2d(2),  # 16
        *block(24, 48), nn.MaxPool2d(2),  # 8
        *block(48, 64), nn.MaxPool2d(2),  # 4: where in the patch matters, so no global pool
        nn.Flatten(), nn.Linear(64 * 16, 64), nn.ReLU(), nn.Dropout(0.2), nn.Linear(64, 5),
    )


def _exported(net):
    """The trained net in eval mode behind the export's interface: uint8 BGR NHWC patches
    in; (N, 5) out: probability, move right and up (top-view px), the turn's cosine and
    sine (unit length)."""
    import torch

    class Verdict(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = net

        def forward(self, x):
            y = self.net(x.permute(0, 3, 1, 2).float() / 127.5 - 1.0)
            turn = y[:, 3:5] / torch.clamp(y[:, 3:5].norm(dim=1, keepdim=True), min=1e-6)
            return torch.cat([torch.sigmoid(y[:, 0:1]), y[:, 1:3] * MOVE_SCALE, turn], 1)

    return Verdict().eval()


# each patch pixel's row and column, from the patch centre
_ROWS, _COLS = np.mgrid[0:64, 0:64].astype(np.float32) - np.float32(31.5)


def half_plane(rng: np.random.Generator, rows: np.ndarray = _ROWS, cols: np.ndarray = _COLS,
                reach: float = 24.0) -> np.ndarray:
    """A float32 mask the shape of ``rows`` (default the patch), 1 on one side of a random
    line passing within ``reach`` px of the centre, with an edge 0.3-3 px soft."""
    a = rng.uniform(0.0, 2.0 * math.pi)
    d = cols * math.cos(a) + rows * math.sin(a) - rng.uniform(-reach, reach)
    return (1.0 / (1.0 + np.exp(np.clip(-d / rng.uniform(0.3, 3.0), -30, 30)))).astype(np.float32)


def pavement(rng: np.random.Generator, rows: np.ndarray = _ROWS, cols: np.ndarray = _COLS,
              spacing: tuple[float, float] = (4.0, 12.0), joint: tuple[float, float] = (0.6, 1.6),
              blur: float = 0.6) -> np.ndarray:
    """A float32 factor <= 1 the shape of ``rows`` (default the patch): the dark joints of
    bricks or tiles laid at a random angle (rows ``spacing`` px apart, bricks 1-3 rows
    long, joints ``joint`` px wide), as paving shows through paint."""
    a = rng.uniform(0.0, math.pi)
    u = cols * math.cos(a) + rows * math.sin(a) + rng.uniform(0.0, 50.0)
    v = -cols * math.sin(a) + rows * math.cos(a) + rng.uniform(0.0, 50.0)
    h = rng.uniform(*spacing)
    length = h * rng.choice([1.0, rng.uniform(1.5, 3.0)])
    row = np.floor(v / h)
    joint_w = rng.uniform(*joint)
    lines = ((v % h) < joint_w) | (((u + (row % 2) * length / 2.0) % length) < joint_w)
    soft = cv2.GaussianBlur(lines.astype(np.float32), (0, 0), blur)
    return 1.0 - np.float32(rng.uniform(0.1, 0.45)) * soft


_SCALE = 96.0 / 64.0  # top-view pixels per patch pixel (SPAN_PX / PATCH_PX)


def _bare_line_end(patch: np.ndarray, target: np.ndarray) -> np.ndarray | None:
    """The patch of a labelled junction with its entrance bar painted out (ground copied
    from beyond it), so that only the separator, ending at the point, is left; None when
    the separator cannot be made out. float32 (64, 64, 3) in and out."""
    mr, mu, cos_t, sin_t = (float(x) for x in target)
    th = math.atan2(sin_t, cos_t)
    pc, pr = mr / _SCALE, -mu / _SCALE  # the point, patch px from the centre (right, down)
    sx, sy = math.sin(th), -math.cos(th)  # along the separator, into the slot
    bx, by = math.cos(th), math.sin(th)   # along the entrance bar
    a = (_COLS - pc) * sx + (_ROWS - pr) * sy
    b = (_COLS - pc) * bx + (_ROWS - pr) * by
    grey = patch.mean(axis=2)
    # across the separator, 10-20 px into the slot: how wide the bright line is
    bb = np.arange(-12, 12.5, 1.0, dtype=np.float32)
    prof = []
    for aa in (10.0, 13.0, 16.0, 19.0):
        xs = 31.5 + pc + aa * sx + bb * bx
        ys = 31.5 + pr + aa * sy + bb * by
        prof.append(cv2.remap(grey, xs[None].astype(np.float32), ys[None].astype(np.float32),
                              cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)[0])
    p = np.mean(prof, axis=0)
    if p.max() - p.min() < 25.0:
        return None
    bright = p > (p.max() + p.min()) / 2.0
    if not bright[10:15].any():
        return None
    hw = bright.sum() / 2.0
    lo, hi = -hw - 2.5, hw + 2.5
    erase = (a >= lo) & (a <= hi) & ~((a >= 0.0) & (np.abs(b) <= hw + 1.5))
    src_a = 2.0 * lo - a  # mirrored across the bar's outer edge
    map_x = (31.5 + pc + src_a * sx + b * bx).astype(np.float32)
    map_y = (31.5 + pr + src_a * sy + b * by).astype(np.float32)
    ground = cv2.remap(patch, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    m = cv2.GaussianBlur(erase.astype(np.float32), (0, 0), 0.7)[..., None]
    return m * ground + (1.0 - m) * patch


def _scene_augment(f: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What real surround views show and the simulator does not draw (float32 NHWC in
    place): paving joints, hard shadows across the patch, and a stitching seam beyond
    which the view is smeared and lit differently."""
    for k in np.nonzero(rng.random(len(f)) < 0.25)[0]:
        f[k] *= pavement(rng)[..., None]
    for k in np.nonzero(rng.random(len(f)) < 0.3)[0]:
        f[k] *= (1.0 - np.float32(rng.uniform(0.25, 0.65)) * half_plane(rng))[..., None]
    for k in np.nonzero(rng.random(len(f)) < 0.3)[0]:
        f[k] = seam(f[k], rng, half_plane)
    return f


def seam(f: np.ndarray, rng: np.random.Generator, mask,
          blur: tuple[float, float] = (0.8, 2.5), smear: tuple[int, int] = (3, 10)) -> np.ndarray:
    """``f`` (float32 HWC) with a stitching seam: the view blurred by ``blur`` px or smeared
    along a random direction over ``smear`` px (as a stitched view far from its camera),
    tinted, and laid over ``f`` where ``mask(rng)`` (drawn last, e.g. :func:`half_plane`)
    is 1."""
    if rng.random() < 0.5:
        other = cv2.GaussianBlur(f, (0, 0), rng.uniform(*blur))
    else:
        n = int(rng.integers(*smear))
        kernel = np.zeros((n, n), np.float32)
        kernel[n // 2] = 1.0 / n
        turn = cv2.getRotationMatrix2D(((n - 1) / 2.0, (n - 1) / 2.0),
                                       rng.uniform(0.0, 180.0), 1.0)
        kernel = cv2.warpAffine(kernel, turn, (n, n))
        other = cv2.filter2D(f, -1, kernel / max(float(kernel.sum()), 1e-6))
    other *= rng.uniform(0.75, 1.25, size=(1, 1, 3)).astype(np.float32)
    m = mask(rng)[..., None]
    return m * other + (1.0 - m) * f


def _augment(batch: np.ndarray, target: np.ndarray, rng: np.random.Generator,
             scene: bool = False, y: np.ndarray | None = None, line_ends: float = 0.0
             ) -> tuple[np.ndarray, np.ndarray]:
    """Photometric changes per patch and left-right mirrors (uint8 NHWC in and out; a
    mirror negates the move to the right and the turn's sine); with ``scene`` also
    :func:`_scene_augment`; a share ``line_ends`` of the positives in ``y`` (changed in
    place) made negatives by :func:`_bare_line_end`."""
    f = batch.astype(np.float32)
    target = target.copy()
    n = len(f)
    if line_ends > 0.0 and y is not None:
        for k in np.nonzero((y > 0.5) & (rng.random(n) < line_ends))[0]:
            bare = _bare_line_end(f[k], target[k])
            if bare is not None:
                f[k], y[k] = bare, 0.0
    mirror = rng.random(n) < 0.5
    f[mirror] = f[mirror, :, ::-1]
    target[mirror, 0] *= -1.0
    target[mirror, 3] *= -1.0
    if scene:
        f = _scene_augment(f, rng)
    f *= rng.uniform(0.8, 1.2, size=(n, 1, 1, 3)).astype(np.float32)  # colour cast
    mean = f.mean(axis=(1, 2, 3), keepdims=True)
    gain = rng.uniform(0.5, 1.4, size=(n, 1, 1, 1)).astype(np.float32)
    light = rng.uniform(0.55, 1.45, size=(n, 1, 1, 1)).astype(np.float32)
    f = f * gain + mean * (light - gain)  # contrast, brightness
    grey = rng.random(n) < 0.1
    f[grey] = f[grey].mean(axis=3, keepdims=True)
    noisy = rng.random(n) < 0.5
    f[noisy] += rng.standard_normal(f[noisy].shape, dtype=np.float32) * np.float32(
        rng.uniform(1, 10))
    out = np.clip(f, 0, 255).astype(np.uint8)
    for k in np.nonzero(rng.random(n) < 0.25)[0]:
        out[k] = cv2.GaussianBlur(out[k], (0, 0), rng.uniform(0.3, 1.2))
    for k in np.nonzero(rng.random(n) < 0.2)[0]:
        ok, buf = cv2.imencode(".jpg", out[k], [cv2.IMWRITE_JPEG_QUALITY,
                                                int(rng.integers(25, 90))])
        out[k] = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out, target


def _loss(out, y, target):
    """Binary cross-entropy on the logit; on the positives also the move (smooth L1 in
    ``MOVE_SCALE`` units) and the turn (squared error of cosine and sine)."""
    import torch
    import torch.nn.functional as nnf

    loss = nnf.binary_cross_entropy_with_logits(out[:, 0], y)
    pos = y > 0.5
    if bool(pos.any()):
        move = nnf.smooth_l1_loss(out[pos, 1:3], target[pos, 0:2] / MOVE_SCALE)
        turn = ((out[pos, 3:5] - target[pos, 2:4]) ** 2).sum(1).mean()
        loss = loss + move + turn
    return loss if torch.isfinite(loss) else loss * 0.0


def train(args: argparse.Namespace) -> None:
    import torch

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    parts = [load(name, args.cache, args.wide_turn_deg) for name in args.train_sets.split(",")]
    data = {k: np.concatenate([p[k] for p in parts]) for k in ("patches", "y_near", "target")}
    keep = data["y_near"] >= 0
    patches, y = data["patches"][keep], data["y_near"][keep].astype(np.float32)
    target = data["target"][keep]
    print(f"{len(y)} training patches, {int(y.sum())} positive", flush=True)
    net = build_model()
    if args.init_onnx is not None:  # fine-tune a shipped file: its batch norms stay frozen
        from onnx_weights import freeze_batch_norms, load_folded_onnx  # tools/: this script's dir

        load_folded_onnx(net, args.init_onnx)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    budget = args.minutes * 60.0
    t0 = time.time()
    step, loss_sum = 0, 0.0
    while True:
        progress = (time.time() - t0) / budget
        if progress >= 1.0 or step >= args.steps:
            break
        progress = max(progress, step / args.steps)
        warm = min(1.0, (progress + 0.002) / 0.03)
        for group in opt.param_groups:
            group["lr"] = args.lr * warm * 0.5 * (1.0 + math.cos(math.pi * progress))
        idx = rng.integers(0, len(y), args.batch)
        yb = y[idx].copy()
        xb, tb = _augment(patches[idx], target[idx], rng, args.scene_augment, yb,
                          args.line_end_negatives)
        x = torch.from_numpy(xb).permute(0, 3, 1, 2).float() / 127.5 - 1.0
        net.train()
        if args.init_onnx is not None:
            freeze_batch_norms(net)
        loss = _loss(net(x), torch.from_numpy(yb), torch.from_numpy(tb))
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        loss_sum += float(loss.detach())
        if step % 200 == 0:
            print(f"  step {step} loss {loss_sum / 200:.4f} {time.time() - t0:.0f} s", flush=True)
            loss_sum = 0.0
    print(f"training time {time.time() - t0:.0f} s, {step} steps", flush=True)
    torch.save(net.state_dict(), args.cache / "point_verifier_last.pt")
    export_onnx(net, args.out)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)", flush=True)


def export_onnx(net, out: Path) -> None:
    import onnx
    import onnxruntime as ort
    import torch

    from semslam.perception.point_verifier import PATCH_PX

    wrapper = _exported(net)
    dummy = torch.zeros(2, PATCH_PX, PATCH_PX, 3, dtype=torch.uint8)
    tmp = out.with_name(out.name + ".tmp")
    torch.onnx.export(wrapper, (dummy,), str(tmp), input_names=["patches"],
                      output_names=["verdict"], dynamic_axes={"patches": {0: "n"},
                                                              "verdict": {0: "n"}},
                      opset_version=17, dynamo=False)
    model = onnx.load(str(tmp))
    onnx.checker.check_model(model)
    model.doc_string = (
        f"Marking-point verifier. input patches: (N, {PATCH_PX}, {PATCH_PX}, 3) uint8 BGR, "
        "from semslam.perception.point_verifier.crop_point_patches. output verdict: "
        "(N, 5) float32: probability that a marking point lies within 20 px of the patch "
        "centre; the move to it along the patch's right and up, top-view px; cosine and sine "
        "of the turn from up to its direction (positive towards the right)"
    )
    onnx.save(model, str(tmp))
    sess = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
    x = np.random.default_rng(0).integers(0, 255, size=(5, PATCH_PX, PATCH_PX, 3), dtype=np.uint8)
    with torch.no_grad():
        ref = wrapper(torch.from_numpy(x)).numpy()
    err = float(np.abs(ref - sess.run(None, {"patches": x})[0]).max())
    if err > 1e-4:
        raise SystemExit(f"ONNX export differs from torch by {err}")
    os.replace(tmp, out)


# ----------------------------------------------------------------------------- evaluation


COMBINE = {
    "grid": lambda c, v: c,
    "verifier": lambda c, v: v,
    "geometric mean": lambda c, v: np.sqrt(c * v),
}


def point_scores(data: dict[str, np.ndarray], score: np.ndarray, threshold: float,
                 uv: np.ndarray | None = None, dirs: np.ndarray | None = None) -> dict:
    """ps2.0 point precision / recall when the candidates keep ``score >= threshold``, at
    their own places or at ``uv`` / ``dirs`` (then the weaker of two within 10 px is
    dropped, as the detector does); candidates near covered labels neither hit nor false,
    the matching greedy by score."""
    from semslam.evaluation.detection_metrics import match_points
    from semslam.perception.marking_points import NMS_RADIUS_PX, suppress_close

    moved = uv is not None
    uv = data["uv"] if uv is None else uv
    dirs = data["dir"] if dirs is None else dirs
    base = data["copy"] == 0
    tp = fp = fn = 0
    starts = np.concatenate([[0], np.cumsum(data["lcount"])])
    view_of = data["view"][base]
    for v in range(len(data["lcount"])):
        sl = slice(starts[v], starts[v + 1])
        lpts, ldir, locc = data["lpts"][sl], data["ldir"][sl], data["locc"][sl]
        k = np.nonzero(base)[0][view_of == v]
        k = k[(score[k] >= threshold) & (data["y"][k] >= 0)]
        if moved and len(k):
            k = k[suppress_close(uv[k], score[k], NMS_RADIUS_PX)]
        match = match_points(uv[k], dirs[k], score[k], lpts[~locc], ldir[~locc])
        hits = int((match >= 0).sum())
        tp, fp, fn = tp + hits, fp + len(k) - hits, fn + int((~locc).sum()) - hits
    p, r = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
    return {"precision": round(p, 4), "recall": round(r, 4),
            "f1": round(2 * p * r / max(p + r, 1e-12), 4), "tp_fp_fn": [tp, fp, fn]}


def evaluate(args: argparse.Namespace) -> dict:
    """The grid alone, then the verifier's score combined with the grid's each way, with
    and without its move and turn; each way's threshold chosen by F1 on the validation
    worlds, reported on the test worlds."""
    from semslam.perception.marking_points import GRID_THRESHOLD
    from semslam.perception.point_verifier import PointVerifier, refined

    verifier = PointVerifier(args.out)
    sets = {name: load(name, args.cache) for name in ("val", "test")}
    verdicts, placed = {}, {}
    for name, data in sets.items():
        verdicts[name] = np.concatenate([verifier.verdicts(data["patches"][k : k + 256])
                                         for k in range(0, len(data["y"]), 256)])
        placed[name] = refined(data["uv"], data["dir"], verdicts[name])
    res: dict = {f"grid alone at {GRID_THRESHOLD}": {
        name: point_scores(d, d["conf"], GRID_THRESHOLD) for name, d in sets.items()}}
    for move in (False, True):
        for how, f in COMBINE.items():
            best = None
            for t in np.arange(0.2, 0.96, 0.05):
                score = f(sets["val"]["conf"], verdicts["val"][:, 0])
                val = point_scores(sets["val"], score, t, *(placed["val"] if move else ()))
                if best is None or val["f1"] > best[0]["f1"]:
                    best = (val, round(float(t), 2))
            val, t = best
            score = f(sets["test"]["conf"], verdicts["test"][:, 0])
            test = point_scores(sets["test"], score, t, *(placed["test"] if move else ()))
            res[f"{how}{', moved' if move else ''}"] = {"threshold": t, "val": val,
                                                        "test": test}
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stage", choices=("mine", "train", "evaluate"), required=True)
    p.add_argument("--sets", default="train,train2,val,test", help="mine: which sets")
    p.add_argument("--train-sets", default="train,train2", help="train: on which sets")
    p.add_argument("--cache", type=Path, default=Path("/tmp/semslam_pv_cache"))
    p.add_argument("--out", type=Path, default=Path("semslam/models/point_verifier.onnx"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument("--minutes", type=float, default=40.0)
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--init-onnx", type=Path, default=None,
                   help="train: fine-tune this exported file; its batch norms stay frozen")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--wide-turn-deg", type=float, default=0.0,
                   help="mine and train: a third patch per training candidate, turned by up "
                   "to this many degrees either way (the shipped file: 0, none)")
    p.add_argument("--scene-augment", action=argparse.BooleanOptionalAction, default=False,
                   help="train: also paving joints, hard shadows and stitching seams")
    p.add_argument("--line-end-negatives", type=float, default=0.0,
                   help="train: this share of the positives made bare line ends (negatives)")
    args = p.parse_args(argv)
    if args.stage == "mine":
        mine(args.sets.split(","), args.cache, args.workers, args.wide_turn_deg)
    elif args.stage == "train":
        train(args)
    else:
        for name, r in evaluate(args).items():
            print(name, json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
