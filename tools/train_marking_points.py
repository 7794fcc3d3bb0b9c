"""Train the marking-point CNN (DMPR-PS style) on simulated ps2.0 top views; export ONNX.

Stages, each re-runnable:

1. render: labelled top views from ``sample_topviews`` (training world seeds only), resized
   to the network input (INTER_AREA, as at run time), cached as ``.npz`` shards in
   ``--cache`` keyed by the sampling arguments (a second run reuses them);
2. train: a small fully convolutional net on ``--threads`` CPU threads, heavy augmentation (colour,
   yellow paint, blur, noise, JPEG, rotations by k*90 deg + small angles, mirror),
   fixed seeds;
3. export: ONNX (opset 17, input ``(1, S, S, 3)`` uint8 BGR, output ``(1, 6, G, G)``
   float32), written atomically, checked against torch;
4. evaluate: the ps2.0 point metric (10 px, 30 deg) through the runtime detector on
   held-out world seeds (never trained on), the slot metric, and the real ps2.0 samples.

Example::

    PYTHONPATH=. python tools/train_marking_points.py --train-worlds 1000:2000 \
        --per-world 8 --epochs 30 --out models/marking_points.onnx

Fine-tuning a shipped file (``--init-onnx``, its batch norms frozen: ``onnx_weights.py``)
on worlds some of whose separators cross the entrance line (``--cross-share``)::

    PYTHONPATH=. python tools/train_marking_points.py --train-worlds 3000:4000 \
        --per-world 8 --epochs 10 --lr 5e-4 --max-minutes 25 --cross-share 0.5 \
        --init-onnx models/marking_points.onnx --out /tmp/marking_points.onnx

``--arch separable`` trains the smaller network of :data:`ARCHITECTURES` instead.
``--distill A.onnx B.onnx`` also teaches the net the mean grid of those files (the pair the
detector averages) on every training batch (:func:`distill_loss`): one grid trained to do
the pair's work.
``--input 384`` trains one that reads 384 px views (a 24 x 24 grid) instead of 256 px.

torch is needed here only; the package runs the exported model with onnxruntime.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from train_point_verifier import half_plane, pavement, seam  # tools/: the script's own dir

INPUT = 256  # network input side, px (``--input``: :func:`set_input_size`)
GRID = 16  # output cells per side: the network's stride is 16
SRC = 600  # ps2.0 top-view side, px


# ----------------------------------------------------------------------------- data


def _scale_points(points: np.ndarray, src: int, dst: int) -> np.ndarray:
    """Pixel coordinates (OpenCV centres) under a resize from src to dst px."""
    k = dst / src
    return (np.asarray(points, float) + 0.5) * k - 0.5


def paint_variation(vary_paint: bool, cross_share: float, faint_share: float = 0.0,
                    worn_share: float = 0.0, dash_share: float = 0.0):
    """The training worlds' :class:`PaintVariation`: ``--vary-paint`` thin lines and stub
    separators, ``--cross-share`` separators painted across the entrance line,
    ``--faint-share`` paint worn faint, ``--worn-share`` separators worn away from their
    junctions, ``--dash-share`` entrance lines painted as dashes across the junctions
    joined by faint yellow; None: as the simulator paints them."""
    from semslam.simulation.topview_samples import PaintVariation

    shares = dict(cross_share=cross_share, faint_share=faint_share, worn_share=worn_share,
                  dash_share=dash_share)
    if vary_paint:
        return PaintVariation(**shares)
    if any(v > 0 for v in shares.values()):
        return PaintVariation(thin_share=0.0, stub_share=0.0, **shares)
    return None


def _render_shard(
    args: tuple[list[int], int, int, str, bool, float, float, int, float, float, float],
) -> str:
    from semslam.simulation.topview_samples import sample_topviews

    seeds, per_world, seed, path, vary, cross, faint, side, worn, slot_share, dash = args
    if os.path.exists(path):
        return path
    images, pts, dirs, shapes, occ, counts = [], [], [], [], [], []
    paint = paint_variation(vary, cross, faint, worn, dash)
    for s in sample_topviews(seeds, per_world, seed, paint=paint, slot_share=slot_share):
        a = s.annotation
        images.append(cv2.resize(s.image, (side, side), interpolation=cv2.INTER_AREA))
        pts.append(np.asarray(a.points, np.float32).reshape(-1, 2))
        dirs.append(np.asarray(a.directions, np.float32).reshape(-1))
        shapes.append(np.asarray(a.shapes, np.int8).reshape(-1))
        occ.append(np.asarray(a.occluded, bool).reshape(-1))
        counts.append(len(a.points))
    tmp = path + ".tmp.npz"
    np.savez(
        tmp,
        images=np.stack(images),
        points=np.concatenate(pts) if pts else np.zeros((0, 2), np.float32),
        directions=np.concatenate(dirs),
        shapes=np.concatenate(shapes),
        occluded=np.concatenate(occ),
        counts=np.asarray(counts, np.int32),
    )
    os.replace(tmp, path)
    return path


def render_dataset(
    seeds: list[int], per_world: int, seed: int, cache: Path, workers: int,
    vary_paint: bool = False,
    cross_share: float = 0.0,
    faint_share: float = 0.0,
    worn_share: float = 0.0,
    slot_share: float = 0.0,
    dash_share: float = 0.0,
) -> dict[str, np.ndarray]:
    """Rendered, resized training views and their labels (600 px coordinates); the worlds'
    paint varied by :func:`paint_variation`; ``slot_share`` of the views taken parking into
    a slot (``sample_topviews``)."""
    cache.mkdir(parents=True, exist_ok=True)
    spec = ([seeds, per_world, seed, INPUT] + (["paint"] if vary_paint else [])
            + ([f"cross{cross_share:g}"] if cross_share > 0 else [])
            + ([f"faint{faint_share:g}"] if faint_share > 0 else [])
            + ([f"worn{worn_share:g}"] if worn_share > 0 else [])
            + ([f"slot{slot_share:g}"] if slot_share > 0 else [])
            + ([f"dash{dash_share:g}"] if dash_share > 0 else []))
    key = hashlib.sha1(json.dumps(spec).encode()).hexdigest()[:10]
    chunk = 25
    jobs = []
    for k in range(0, len(seeds), chunk):
        part = seeds[k : k + chunk]
        jobs.append((part, per_world, seed + k, str(cache / f"mp_{key}_{k:05d}.npz"), vary_paint,
                     cross_share, faint_share, INPUT, worn_share, slot_share, dash_share))
    t0 = time.time()
    if workers > 1:
        with mp.get_context("spawn").Pool(workers) as pool:
            for n, _ in enumerate(pool.imap(_render_shard, jobs), 1):
                print(f"render {n}/{len(jobs)} shards {time.time() - t0:.0f} s", flush=True)
    else:
        for n, job in enumerate(jobs, 1):
            _render_shard(job)
            print(f"render {n}/{len(jobs)} shards {time.time() - t0:.0f} s", flush=True)
    parts = [np.load(j[3]) for j in jobs]
    out = {name: np.concatenate([p[name] for p in parts]) for name in parts[0].files}
    return out


def _training_views(args: argparse.Namespace) -> dict[str, np.ndarray]:
    """The training views of every ``lo:hi`` range in ``--train-worlds`` (comma-separated).

    Range k is sampled with data seed ``--data-seed + 1000 k`` and cached on its own, so
    adding a range keeps the cache of the earlier ones.
    """
    parts = []
    for k, span in enumerate(args.train_worlds.split(",")):
        lo, hi = (int(v) for v in span.split(":"))
        seed = args.data_seed + 1000 * k
        parts.append(render_dataset(list(range(lo, hi)), args.per_world, seed, args.cache,
                                    args.workers, args.vary_paint, args.cross_share,
                                    args.faint_share, args.worn_share, args.slot_share,
                                    args.dash_share))
    return {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}


def _labels_at_input(data: dict[str, np.ndarray]) -> list[tuple[np.ndarray, ...]]:
    """Per view: points at the input scale, directions, shapes, occluded."""
    out, k = [], 0
    for n in data["counts"]:
        sl = slice(k, k + int(n))
        out.append(
            (
                _scale_points(data["points"][sl], SRC, INPUT),
                data["directions"][sl].astype(float),
                data["shapes"][sl].astype(int),
                data["occluded"][sl].astype(bool),
            )
        )
        k += int(n)
    return out


# ----------------------------------------------------------------------------- augmentation


def _centred_grid(side: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column offsets from the middle of a ``side`` px view, float32."""
    rows, cols = np.mgrid[0:side, 0:side].astype(np.float32) - np.float32((side - 1) / 2)
    return rows, cols


_ROWS, _COLS = _centred_grid(INPUT)


def set_input_size(side: int) -> None:
    """Train and export a network reading ``side`` px views (a multiple of 16; 256 shipped).

    The grid has ``side / 16`` cells per side; the augmentation's shift and blur scale with
    the side, so they stay the same in metres."""
    global INPUT, GRID, _ROWS, _COLS
    if side < 64 or side % 16:
        raise SystemExit(f"--input {side}: expected a multiple of 16, at least 64")
    INPUT, GRID = side, side // 16
    _ROWS, _COLS = _centred_grid(side)


def _half_plane(rng: np.random.Generator) -> np.ndarray:
    """An (INPUT, INPUT) float32 mask, 1 on one side of a random line through the view's
    middle part, with an edge 0.3-3 px soft."""
    return half_plane(rng, _ROWS, _COLS, reach=0.4 * INPUT)


def _pavement(rng: np.random.Generator) -> np.ndarray:
    """An (INPUT, INPUT) float32 factor <= 1: the dark joints of bricks or tiles laid at a
    random angle (rows 3-8 px apart at the input's 2.3 cm per px, bricks 1-3 rows long)."""
    return pavement(rng, _ROWS, _COLS, spacing=(3.0, 8.0), joint=(0.5, 1.1), blur=0.5)


def scene_augment(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What real surround views show and the simulator does not draw (uint8 in and out):
    paving joints, a hard shadow over part of the view, a stitching seam beyond which the
    view is blurred or smeared and lit differently (``--scene-augment``; the verifier's
    ``tools/train_point_verifier.py`` has the same at its patch scale)."""
    f = img.astype(np.float32)
    if rng.random() < 0.25:
        f *= _pavement(rng)[..., None]
    if rng.random() < 0.3:
        f *= (1.0 - np.float32(rng.uniform(0.25, 0.65)) * _half_plane(rng))[..., None]
    if rng.random() < 0.3:
        f = seam(f, rng, _half_plane, blur=(0.6, 1.8), smear=(3, 8))
    return np.clip(f, 0, 255).astype(np.uint8)


def augment(
    image: np.ndarray, labels: tuple[np.ndarray, ...], rng: np.random.Generator,
    scene: bool = False,
) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """A randomly transformed copy of one input-size view and its labels.

    Geometry: rotation by k * 90 deg plus up to +-12 deg (one case in six any angle),
    scale 0.95-1.05, shift up to 8 px, mirror left-right; points and directions go
    through the same affine map (a mirror flips du), points leaving the image are dropped.
    Colour: brightness, contrast, gamma, per-channel gains, hue shift, yellowed or greyed
    paint, illumination gradients, blur, noise, JPEG; with ``scene`` first
    :func:`scene_augment`.
    """
    pts, dirs, shapes, occ = labels
    n = INPUT
    c = (n - 1) / 2.0
    angle = 90.0 * int(rng.integers(4))
    angle += rng.uniform(-180, 180) if rng.random() < 1 / 6 else rng.uniform(-12, 12)
    scale = rng.uniform(0.95, 1.05)
    A = cv2.getRotationMatrix2D((c, c), angle, scale)
    if rng.random() < 0.5:  # mirror u before rotating
        F = np.array([[-1.0, 0.0, n - 1.0], [0.0, 1.0, 0.0], [0, 0, 1]])
        A = A @ F
    A[:, 2] += rng.uniform(-8, 8, size=2) * (n / 256)
    img = cv2.warpAffine(
        image, A, (n, n), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
    if len(pts):
        q = pts @ A[:, :2].T + A[:, 2]
        d = np.stack([np.cos(dirs), np.sin(dirs)], 1) @ A[:, :2].T
        nd = np.arctan2(d[:, 1], d[:, 0])
        keep = (q[:, 0] >= -0.5) & (q[:, 0] < n - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] < n - 0.5)
        pts, dirs, shapes, occ = q[keep], nd[keep], shapes[keep], occ[keep]
    if scene:
        img = scene_augment(img, rng)
    img = _photometric(img, rng)
    return img, (pts, dirs, shapes, occ)


def _photometric(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    f = img.astype(np.float32)
    if rng.random() < 0.3:  # paint to yellow: pull blue down where bright and unsaturated
        grey = f.mean(axis=2)
        bright = np.clip((grey - np.percentile(grey, 80)) / 60.0, 0, 1)
        f[..., 0] *= 1.0 - rng.uniform(0.3, 0.7) * bright
    if rng.random() < 0.5:  # hue shift
        hsv = cv2.cvtColor(np.clip(f, 0, 255).astype(np.uint8), cv2.COLOR_BGR2HSV)
        hsv[..., 0] = ((hsv[..., 0].astype(int) + int(rng.integers(-12, 13))) % 180).astype(
            np.uint8
        )
        f = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR).astype(np.float32)
    f *= rng.uniform(0.8, 1.2, size=3).astype(np.float32)  # colour cast
    mean = f.mean()
    gain = np.float32(rng.uniform(0.5, 1.4))
    f = f * gain + np.float32(mean * (rng.uniform(0.55, 1.45) - gain))  # contrast, light
    if rng.random() < 0.4:  # illumination gradient / light pool
        yy, xx = np.mgrid[0:INPUT, 0:INPUT].astype(np.float32) / INPUT
        g = rng.uniform(-0.5, 0.5) * (xx - 0.5) + rng.uniform(-0.5, 0.5) * (yy - 0.5)
        f *= (1.0 + g)[..., None]
    if rng.random() < 0.1:
        f[:] = f.mean(axis=2, keepdims=True)
    gamma = rng.uniform(0.7, 1.4) if rng.random() < 0.5 else 1.0
    if rng.random() < 0.3:
        s = rng.uniform(0.3, 1.3) * (INPUT / 256)
        f = cv2.GaussianBlur(f, (0, 0), s)
    if rng.random() < 0.5:
        f += rng.standard_normal(f.shape, dtype=np.float32) * np.float32(rng.uniform(1, 10))
    out = np.clip(f, 0, 255).astype(np.uint8)
    if gamma != 1.0:  # a table on the 8-bit image: 20x cheaper than a float power
        out = cv2.LUT(out, np.clip(255.0 * (np.arange(256) / 255.0) ** gamma, 0, 255)
                      .astype(np.uint8))
    if rng.random() < 0.3:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(25, 90))])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def encode_targets(labels: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(6, G, G) targets [conf, shape(L), ox, oy, cos, sin] and a (G, G) confidence weight
    (0 in cells holding an occluded point: neither required nor punished)."""
    pts, dirs, shapes, occ = labels
    t = np.zeros((6, GRID, GRID), np.float32)
    w = np.ones((GRID, GRID), np.float32)
    cell = INPUT / GRID
    for (u, v), a, s, o in zip(pts, dirs, shapes, occ, strict=True):
        x, y = (u + 0.5) / cell, (v + 0.5) / cell
        col, row = min(int(x), GRID - 1), min(int(y), GRID - 1)
        if o:
            if t[0, row, col] == 0:
                w[row, col] = 0.0
            continue
        w[row, col] = 1.0
        t[:, row, col] = [1.0, float(s), x - col, y - row, math.cos(a), math.sin(a)]
    return t, w


# ----------------------------------------------------------------------------- model


ARCHITECTURES = ("conv", "separable")
"""``--arch``: ``conv``, eight 3x3 convolutions (0.47 M parameters, 0.215 G multiply-adds at
256 px: the shipped pair of 2026-11-22/23); ``separable``, the same strides and widths with
the last five convolutions depthwise-separable (a 3x3 per channel, then a 1x1 across them;
0.08 M parameters, 0.066 G multiply-adds, 4.2 ms against 11.7 ms on a Zen 1 core; a pair
trained 50 min per run lost 3 points of held-out recall: not shipped, ``BENCHMARKS.md``, "A
smaller grid network for the Zen 1 machine")."""


def build_model(arch: str = "conv"):
    """The grid network: (N, 3, S, S) normalised BGR in, (N, 6, S / 16, S / 16) logits out."""
    import torch.nn as nn

    def cbr(i: int, o: int, s: int = 1) -> list:
        return [nn.Conv2d(i, o, 3, s, 1, bias=False), nn.BatchNorm2d(o), nn.ReLU(inplace=True)]

    def separable(i: int, o: int, s: int = 1) -> list:
        across = [nn.Conv2d(i, o, 1, bias=False), nn.BatchNorm2d(o), nn.ReLU(inplace=True)]
        return [nn.Conv2d(i, i, 3, s, 1, groups=i, bias=False), nn.BatchNorm2d(i),
                nn.ReLU(inplace=True), *across]

    if arch not in ARCHITECTURES:
        raise ValueError(f"unknown architecture {arch!r}, expected one of {ARCHITECTURES}")
    late = cbr if arch == "conv" else separable
    layers = (
        cbr(3, 16, 2)
        + cbr(16, 32, 2)
        + cbr(32, 64, 2)
        + late(64, 64)
        + late(64, 64)
        + late(64, 128, 2)
        + late(128, 128)
        + late(128, 128)
    )
    return nn.Sequential(*layers, nn.Conv2d(128, 6, 1))


def _to_tensor(batch_u8: np.ndarray):
    import torch

    x = torch.from_numpy(batch_u8).permute(0, 3, 1, 2).float()
    return x / 127.5 - 1.0


def loss_fn(out, target, weight):
    """The grid's loss against the labels' (N, 6, G, G) target grid, with the per-cell
    ``weight`` on the confidence term; the other terms count at the labelled points."""
    return _grid_loss(out, target, weight, target[:, 0])


def distill_loss(out, teacher, weight):
    """:func:`loss_fn`'s terms against a teacher's activated (N, 6, G, G) grid instead of the
    labels: its confidence and shape as soft targets, its offsets and directions weighted by
    its confidence (and ``weight``). The teacher of ``--distill`` is the mean of the files'
    grids, which is what the runtime detector computes from the pair
    (``MarkingPointDetector.grid``)."""
    return _grid_loss(out, teacher, weight, teacher[:, 0] * weight)[0]


def _grid_loss(out, target, weight, at):
    """Confidence (binary cross-entropy, positives weighing 5x: few per view, DMPR-PS-like),
    then shape, offset and direction where ``at`` (per cell, >= 0) says a point is; the
    total and its four terms."""
    import torch
    import torch.nn.functional as nnf

    pos = target[:, 0]
    conf = nnf.binary_cross_entropy_with_logits(out[:, 0], pos, reduction="none")
    lconf = (conf * weight * (1.0 + 4.0 * pos)).sum() / weight.sum()
    mass = at.sum().clamp(min=1.0)
    lshape = (nnf.binary_cross_entropy_with_logits(out[:, 1], target[:, 1], reduction="none")
              * at).sum() / mass
    off = torch.sigmoid(out[:, 2:4])
    loff = (((off - target[:, 2:4]) ** 2).sum(1) * at).sum() / mass
    d = torch.tanh(out[:, 4:6])
    ldir = (((d - target[:, 4:6]) ** 2).sum(1) * at).sum() / mass
    return lconf + 0.5 * lshape + 10.0 * loff + 2.0 * ldir, (lconf, lshape, loff, ldir)


def load_teachers(paths: list[Path], arch: str) -> list:
    """The ``--distill`` files as frozen torch nets (their folded weights, eval mode)."""
    from onnx_weights import load_folded_onnx  # tools/: this script's dir

    nets = []
    for path in paths:
        net = build_model(arch)
        load_folded_onnx(net, path)
        net.eval()
        for param in net.parameters():
            param.requires_grad_(False)
        nets.append(net)
    return nets


def teacher_grid(teachers: list, x):
    """The teachers' mean activated grid (sigmoid on channels 0-3, tanh on 4-5) for ``x``."""
    import torch

    with torch.no_grad():
        grids = []
        for net in teachers:
            y = net(x).float()
            grids.append(torch.cat([torch.sigmoid(y[:, 0:4]), torch.tanh(y[:, 4:6])], dim=1))
        return torch.stack(grids).mean(0)


class Exported:
    """Wraps the trained net: uint8 BGR NHWC in, activated (1, 6, G, G) grid out."""

    @staticmethod
    def make(net):
        import torch
        import torch.nn as nn

        class Wrapper(nn.Module):
            def __init__(self, net):
                super().__init__()
                self.net = net

            def forward(self, x):
                x = x.permute(0, 3, 1, 2).float() / 127.5 - 1.0
                y = self.net(x)
                return torch.cat(
                    [torch.sigmoid(y[:, 0:4]), torch.tanh(y[:, 4:6])],
                    dim=1,
                )

        return Wrapper(net).eval()


def export_onnx(net, out: Path) -> None:
    import torch

    net.eval()
    wrapper = Exported.make(net)
    dummy = torch.zeros(1, INPUT, INPUT, 3, dtype=torch.uint8)
    tmp = out.with_name(out.name + ".tmp")
    torch.onnx.export(
        wrapper,
        (dummy,),
        str(tmp),
        input_names=["image"],
        output_names=["grid"],
        opset_version=17,
        dynamo=False,
    )
    import onnx

    model = onnx.load(str(tmp))
    onnx.checker.check_model(model)
    model.doc_string = (
        f"DMPR-PS-style marking points. input image: (1, {INPUT}, {INPUT}, 3) uint8 BGR, "
        f"a ps2.0 top view resized with INTER_AREA. output grid: (1, 6, {GRID}, {GRID}) "
        "float32 [confidence, P(L junction), x offset, y offset in the cell (0-1), "
        "cos, sin of the direction in image coordinates]"
    )
    onnx.save(model, str(tmp))
    import onnxruntime as ort

    sess = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    x = rng.integers(0, 255, size=(1, INPUT, INPUT, 3), dtype=np.uint8)
    with torch.no_grad():
        ref = wrapper(torch.from_numpy(x)).numpy()
    got = sess.run(None, {"image": x})[0]
    err = float(np.abs(ref - got).max())
    if err > 1e-3:
        raise SystemExit(f"ONNX export differs from torch by {err}")
    os.replace(tmp, out)


# ----------------------------------------------------------------------------- training


def _augmented_batch(
    images: np.ndarray, labels: list, idx: np.ndarray, seed: int, scene: bool = False
) -> tuple[np.ndarray, ...]:
    """One augmented batch: (uint8 NHWC images, targets, weights), from its own seed.

    (Made in the training loop: a separate augmenting process only competes with torch's
    two threads on this 2-core machine, 0.31 against 0.27 s per step.)
    """
    rng = np.random.default_rng(seed)
    xs, ts, ws = [], [], []
    for i in idx:
        img, lab = augment(images[i], labels[i], rng, scene)
        t, w = encode_targets(lab)
        xs.append(img)
        ts.append(t)
        ws.append(w)
    return np.stack(xs), np.stack(ts), np.stack(ws)


def native_bf16() -> bool:
    """Whether this CPU computes bfloat16 in hardware (AVX-512 BF16 or AMX, Linux flags).
    Without it torch emulates bf16 and a step is about 2x slower than in float32."""
    try:
        flags = Path("/proc/cpuinfo").read_text().split()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def train(args: argparse.Namespace) -> None:
    """Train on ``--threads`` torch threads; bf16 autocast and channels-last convolutions
    where the CPU has bf16 in hardware (:func:`native_bf16`) and ``--fp32`` is not given
    (2.3x faster steps on the AVX-512 BF16 CPU of 2026-11-22; on one without it, 1.1 s
    against 0.55 s per step in float32); the weights and the export stay float32."""
    import torch

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    data = _training_views(args)
    images = data["images"]
    labels = _labels_at_input(data)
    n = len(images)
    print(f"{n} training views, {int(data['counts'].sum())} points", flush=True)
    net = build_model(args.arch)
    if args.init is not None:  # continue from saved weights (a second, shorter run)
        net.load_state_dict(torch.load(args.init))
    if args.init_onnx is not None:  # fine-tune a shipped file: its batch norms stay frozen
        from onnx_weights import freeze_batch_norms, load_folded_onnx  # tools/: this script's dir

        load_folded_onnx(net, args.init_onnx)
    fast = not args.fp32 and native_bf16()
    print(f"steps in {'bf16' if fast else 'float32'}", flush=True)
    teachers = load_teachers(args.distill, args.arch) if args.distill else []
    if fast:
        net = net.to(memory_format=torch.channels_last)
        teachers = [t.to(memory_format=torch.channels_last) for t in teachers]
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    steps_per_epoch = n // args.batch
    total = steps_per_epoch * args.epochs
    ckpt = args.cache / f"{args.out.stem}_last.pt"  # not beside the model: package data
    budget = args.max_minutes * 60.0 if args.max_minutes else float("inf")
    jobs = [
        (order[b * args.batch : (b + 1) * args.batch], args.seed * 1_000_003 + e * 10_007 + b)
        for e, order in enumerate(rng.permutation(n) for _ in range(args.epochs))
        for b in range(steps_per_epoch)
    ]
    batches = (_augmented_batch(images, labels, idx, seed, args.scene_augment)
               for idx, seed in jobs)
    t0 = time.time()
    step = 0
    progress = 0.0
    loss_sum = 0.0
    for xs, ts, ws in batches:
        # schedule on the larger of step and wall-clock progress: warm-up then cosine,
        # so a slow (shared) machine still anneals inside --max-minutes
        progress = max(step / total, (time.time() - t0) / budget)
        if progress >= 1.0:
            break
        warm = min(1.0, (progress + 0.002) / 0.05)
        for group in opt.param_groups:
            group["lr"] = args.lr * warm * 0.5 * (1.0 + math.cos(math.pi * progress))
        net.train()
        if args.init_onnx is not None:
            freeze_batch_norms(net)
        x = _to_tensor(xs)
        if fast:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=fast):
            out = net(x)
        weight = torch.from_numpy(ws)
        loss, _ = loss_fn(out.float(), torch.from_numpy(ts), weight)
        if teachers:
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=fast):
                taught = teacher_grid(teachers, x)
            mix = args.distill_weight
            loss = (1.0 - mix) * loss + mix * distill_loss(out.float(), taught.float(), weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        loss_sum += float(loss.detach())
        if step % 50 == 0:
            print(f"  step {step} loss {loss_sum / 50:.4f} {time.time() - t0:.0f} s", flush=True)
            loss_sum = 0.0
        if step % steps_per_epoch == 0:
            print(f"epoch {step // steps_per_epoch}/{args.epochs} {time.time() - t0:.0f} s",
                  flush=True)
            torch.save(net.state_dict(), ckpt)
    print(f"training time {time.time() - t0:.0f} s, {step} steps", flush=True)
    net = net.to(memory_format=torch.contiguous_format)
    torch.save(net.state_dict(), ckpt)
    export_onnx(net, args.out)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)", flush=True)


# ----------------------------------------------------------------------------- evaluation


def match_points(det_uv, det_dir, lab_uv, lab_dir, dist_px=10.0, angle_deg=30.0):
    """Greedy one-to-one matching by the ps2.0 rule: (hits per detection, label index or -1)."""
    det_uv = np.asarray(det_uv, float).reshape(-1, 2)
    lab_uv = np.asarray(lab_uv, float).reshape(-1, 2)
    assign = np.full(len(det_uv), -1)
    if not len(det_uv) or not len(lab_uv):
        return assign
    d = np.linalg.norm(det_uv[:, None] - lab_uv[None], axis=2)
    da = np.abs(np.angle(np.exp(1j * (np.asarray(det_dir)[:, None] - np.asarray(lab_dir)[None]))))
    ok = (d <= dist_px) & (da <= math.radians(angle_deg))
    used = np.zeros(len(lab_uv), bool)
    for k in np.argsort(d, axis=None):
        i, j = divmod(int(k), len(lab_uv))
        if ok[i, j] and assign[i] < 0 and not used[j]:
            assign[i] = j
            used[j] = True
    return assign


def evaluate(
    model: Path,
    worlds: list[int],
    per_world: int,
    seed: int,
    real: Path | None,
    threshold: float | None = None,
) -> dict:
    from semslam.io.dmpr_labels import read_dmpr_labels
    from semslam.perception.marking_points import MarkingPointDetector
    from semslam.perception.slots import infer_slots
    from semslam.simulation.topview_samples import sample_topviews

    det = (
        MarkingPointDetector(model) if threshold is None else MarkingPointDetector(model, threshold)
    )
    res: dict = {}
    # counts: [tp, fp, fn] visible-only (occluded labels: a hit on one is neither) and all
    vis = np.zeros(3)
    full = np.zeros(3)
    slots = np.zeros(3)
    kinds = {1: np.zeros(3), 2: np.zeros(3), 3: np.zeros(3)}
    shape_ok = shape_n = 0
    times = []
    failures = []
    for s in sample_topviews(worlds, per_world, seed):
        a = s.annotation
        t = time.perf_counter()
        pts = det.detect(s.image)
        times.append(time.perf_counter() - t)
        uv = np.array([p.uv for p in pts]).reshape(-1, 2)
        dd = np.array([p.direction for p in pts])
        assign = match_points(uv, dd, a.points, a.directions)
        hit = assign >= 0
        occ = np.asarray(a.occluded, bool)
        hit_vis = hit & ~occ[assign] if len(occ) else hit
        matched = np.zeros(len(a.points), bool)
        matched[assign[hit]] = True
        vis += [hit_vis.sum(), (~hit).sum(), (~matched & ~occ).sum()]
        full += [hit.sum(), (~hit).sum(), (~matched).sum()]
        for k in np.nonzero(hit)[0]:
            shape_n += 1
            shape_ok += int(pts[k].shape.value == ("T", "L")[int(a.shapes[assign[k]])])
        if (~hit).sum() or (~matched & ~occ).sum():
            failures.append(
                (s.world_seed, s.render_seed, int((~hit).sum()), int((~matched & ~occ).sum()))
            )
        # slots: a hit if both entrance points match the labelled slot's points (either order)
        ds = infer_slots(pts)
        lab = {(int(i) - 1, int(j) - 1): int(t) for i, j, t, _ in a.slots}
        det_pairs = set()
        for sl in ds:
            i, j = assign[sl.i], assign[sl.j]
            det_pairs.add((int(i), int(j)) if i >= 0 and j >= 0 else (-1, -1))
        # visible slots only: both points unoccluded
        lab_vis = {k: v for k, v in lab.items() if not occ[k[0]] and not occ[k[1]]}
        tp = sum(1 for k in lab_vis if k in det_pairs)
        fp = sum(1 for k in det_pairs if k not in lab)
        slots += [tp, fp, len(lab_vis) - tp]
        for k, v in lab_vis.items():
            kinds[v] += [int(k in det_pairs), 0, int(k not in det_pairs)]
    pr = lambda c: (c[0] / max(c[0] + c[1], 1), c[0] / max(c[0] + c[2], 1))  # noqa: E731
    res["heldout_views"] = len(times)
    res["points_visible"] = dict(zip(("precision", "recall"), pr(vis), strict=True)) | {
        "tp_fp_fn": vis.astype(int).tolist()
    }
    res["points_all"] = dict(zip(("precision", "recall"), pr(full), strict=True)) | {
        "tp_fp_fn": full.astype(int).tolist()
    }
    res["shape_accuracy"] = shape_ok / max(shape_n, 1)
    res["slots_visible"] = dict(zip(("precision", "recall"), pr(slots), strict=True)) | {
        "tp_fp_fn": slots.astype(int).tolist()
    }
    res["slot_recall_by_type"] = {k: float(pr(v)[1]) for k, v in kinds.items()}
    res["detect_ms_median"] = 1000 * float(np.median(times))
    res["worst_views"] = failures[:10]
    if real is not None and (real / "images").is_dir():
        rc = np.zeros(3)
        rs = np.zeros(3)
        for f in sorted((real / "images").glob("*.jpg")):
            lab = read_dmpr_labels(real / "labels" / (f.stem + ".json"))
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            pts = det.detect(img)
            uv = np.array([p.uv for p in pts]).reshape(-1, 2)
            dd = np.array([p.direction for p in pts])
            assign = match_points(uv, dd, lab.points, lab.directions)
            matched = np.zeros(len(lab.points), bool)
            matched[assign[assign >= 0]] = True
            rc += [(assign >= 0).sum(), (assign < 0).sum(), (~matched).sum()]
            ds = infer_slots(pts)
            pairs = {(int(assign[sl.i]), int(assign[sl.j])) for sl in ds}
            labs = {(int(i) - 1, int(j) - 1) for i, j, _, _ in lab.slots}
            tp = len(pairs & labs)
            rs += [tp, len(pairs) - tp, len(labs) - tp]
        res["real_points"] = dict(zip(("precision", "recall"), pr(rc), strict=True)) | {
            "tp_fp_fn": rc.astype(int).tolist()
        }
        res["real_slots"] = dict(zip(("precision", "recall"), pr(rs), strict=True)) | {
            "tp_fp_fn": rs.astype(int).tolist()
        }
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--train-worlds",
        default="1000:2000",
        help="world seeds lo:hi (hi excluded), comma-separated ranges",
    )
    p.add_argument("--per-world", type=int, default=8, help="views per training world")
    p.add_argument("--epochs", type=int, default=8)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--seed", type=int, default=1, help="weights, order, augmentation")
    p.add_argument("--data-seed", type=int, default=1, help="training views (sampling)")
    p.add_argument("--max-minutes", type=float, default=44.0, help="stop training after this")
    p.add_argument("--workers", type=int, default=2, help="render processes")
    p.add_argument("--cache", type=Path, default=Path("/tmp/semslam_mp_cache"))
    p.add_argument("--out", type=Path, default=Path("models/marking_points.onnx"))
    p.add_argument("--eval-worlds", default="0:100", help="held-out world seeds lo:hi")
    p.add_argument("--eval-per-world", type=int, default=5)
    p.add_argument(
        "--real",
        type=Path,
        default=Path(__file__).resolve().parents[2] / "shared/realdata/ps2.0-samples",
    )
    p.add_argument("--init", type=Path, default=None, help="start from these torch weights")
    p.add_argument("--init-onnx", type=Path, default=None,
                   help="fine-tune this exported (float) file; its batch norms stay frozen")
    p.add_argument("--cross-share", type=float, default=0.0,
                   help="share of training worlds whose separators cross the entrance line")
    p.add_argument("--faint-share", type=float, default=0.0,
                   help="share of training worlds whose paint is worn faint")
    p.add_argument("--worn-share", type=float, default=0.0,
                   help="share of training separators worn away from their junctions")
    p.add_argument("--slot-share", type=float, default=0.0,
                   help="share of training views taken parking into a slot")
    p.add_argument("--dash-share", type=float, default=0.0,
                   help="share of training worlds whose entrance lines are dashes at the "
                        "junctions joined by faint yellow (PaintVariation.dash_share)")
    p.add_argument("--distill", type=Path, nargs="+", default=[],
                   help="float grid files whose mean grid the net also learns (distill_loss)")
    p.add_argument("--distill-weight", type=float, default=0.5,
                   help="share of the loss from --distill's grid (the rest from the labels)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (1 on a shared machine)")
    p.add_argument("--arch", choices=ARCHITECTURES, default="conv",
                   help="grid network (ARCHITECTURES)")
    p.add_argument("--input", type=int, default=256,
                   help="network input side, px (a multiple of 16; set_input_size)")
    p.add_argument("--eval-only", action="store_true", help="evaluate --out, do not train")
    p.add_argument("--fp32", action="store_true",
                   help="float32 convolutions (default: bf16 autocast and channels last "
                   "where the CPU has bf16 in hardware)")
    p.add_argument("--vary-paint", action="store_true",
                   help="training worlds with thinner lines and stub separators at random")
    p.add_argument("--threshold", type=float, default=None, help="point confidence (eval)")
    p.add_argument("--scene-augment", action="store_true",
                   help="also paving joints, hard shadows and stitching seams (scene_augment)")
    args = p.parse_args(argv)
    set_input_size(args.input)
    if not args.eval_only:
        train(args)
    lo, hi = (int(v) for v in args.eval_worlds.split(":"))
    res = evaluate(
        args.out, list(range(lo, hi)), args.eval_per_world, 12345, args.real, args.threshold
    )
    print(json.dumps(res, indent=None).replace(', "', ',\n "'))
    return 0


if __name__ == "__main__":
    sys.exit(main())
