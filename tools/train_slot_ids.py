"""Train the painted slot-ID reader (``models/slot_ids.onnx``) on simulated top views.

Stages (all by default; data are cached in ``--cache``):

1. data: top views from ``sample_topviews``-style sampling (same aisle poses, render
   seeds), with the renderer's drawn solids captured so every painted label gets an
   occlusion share. Per label near the vehicle, crops from :func:`crop_id_patch` at the
   slot's entrance with detector-like jitter (entrance points +-3 px sigma, direction
   3 deg sigma, scale +-8 %): target = the label when the text box is fully inside the
   image, off the ego box and < 2 % covered; blank when < 15 % of it is visible;
   otherwise skipped (ambiguous). More blanks: the same entrances looked at the wrong
   way (into the aisle). Train worlds 1000-1399, calibration 100-199, test 0-99.
2. train: small conv-only CTC model (2D CNN, max over height, 1D convs along the
   text) over 0-9 A-Z, heavy augmentation (brightness, contrast, gamma, blur, noise,
   JPEG, dark / bright blobs at the left and right margins).
3. calibrate: temperature on the logits fit (NLL of "the reading is right") on the
   calibration worlds, then raised until labels given with confidence >= 0.9 are >= 99.8 %
   right there; baked into the exported graph (opset 17).
4. evaluate on the test worlds: accuracy on readable IDs, confidence >= 0.9 share and
   its accuracy, a reliability table, blank handling; timing of a batch of 4.

Usage (from the repository root)::

    PYTHONPATH=. python tools/train_slot_ids.py --out models/slot_ids.onnx
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np

from semslam.perception.slot_ids import (
    ALPHABET,
    DEPTH_RANGE_M,
    PATCH_HEIGHT,
    PATCH_WIDTH,
    PX_PER_M,
    crop_id_patch,
    readings_from_probs,
)
from semslam.simulation.render_topview import TopviewRenderer
from semslam.simulation.topview_samples import random_aisle_pose
from semslam.simulation.world import make_world

SETS = {
    "train": (range(1000, 1400), 8, 11, 2),  # world seeds, views per world, seed, crops/label
    "train2": (range(1400, 1600), 8, 44, 2),  # more training worlds (continuation)
    "train3": (range(1600, 2000), 8, 55, 2),
    # worlds whose slots carry a random letter each (see relabelled_world)
    "letters": (range(2000, 2400), 8, 66, 2),
    "calib": (range(100, 200), 8, 22, 1),
    "test": (range(0, 100), 8, 33, 1),
}
READABLE, BLANK = 0, 1  # status of a crop (ambiguous ones are not stored)


# ---------------------------------------------------------------- data


def _grid(box: np.ndarray, n: int = 9, m: int = 5) -> np.ndarray:
    """(n*m, 2) points spread over a quadrilateral box (bl, br, tr, tl)."""
    s, t = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(m) + 0.5) / m)
    s, t = s.ravel()[:, None], t.ravel()[:, None]
    bl, br, tr, tl = box
    return (1 - t) * ((1 - s) * bl + s * br) + t * ((1 - s) * tl + s * tr)


def _label_status(box, polys, ego, n):
    """(inside share, visible share, occluded share) of a text box in pixels."""
    g = _grid(box)
    v0, v1, u0, u1 = ego
    inside = (g[:, 0] >= 0) & (g[:, 0] <= n - 1) & (g[:, 1] >= 0) & (g[:, 1] <= n - 1)
    inside &= ~(
        (g[:, 0] >= u0 - 0.5)
        & (g[:, 0] <= u1 - 0.5)
        & (g[:, 1] >= v0 - 0.5)
        & (g[:, 1] <= v1 - 0.5)
    )
    occ = np.zeros(len(g), bool)
    lo, hi = box.min(axis=0), box.max(axis=0)
    for poly in polys:
        if (poly.max(axis=0) < lo).any() or (poly.min(axis=0) > hi).any():
            continue
        p = poly.reshape(-1, 1, 2).astype(np.float32)
        for k in np.nonzero(~occ)[0]:
            if cv2.pointPolygonTest(p, (float(g[k, 0]), float(g[k, 1])), False) >= 0:
                occ[k] = True
    return float(inside.mean()), float((inside & ~occ).mean()), float(occ.mean())


def _jittered(rng, e, d, strong=1.0):
    e = e + np.clip(rng.normal(0.0, 3.0 * strong, (2, 2)), -8, 8)
    a = math.radians(float(np.clip(rng.normal(0.0, 3.0 * strong), -8, 8)))
    c, s = math.cos(a), math.sin(a)
    return e, np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])


def relabelled_world(world, rng: np.random.Generator):
    """``world`` with every slot's ID drawn afresh: a letter (uniform over the simulator's
    ``LABEL_CHARS``) and a number 1-99. The simulator gives one letter to a whole row and
    numbers the row from 1, so a letter is about a tenth as common in its IDs as a digit
    is; in these worlds every letter is as common as a digit."""
    import dataclasses

    from semslam.simulation.world import LABEL_CHARS

    def label() -> str:
        return f"{LABEL_CHARS[int(rng.integers(len(LABEL_CHARS)))]}{int(rng.integers(1, 100))}"

    slots = tuple(dataclasses.replace(s, label=label()) for s in world.slots)
    return dataclasses.replace(world, slots=slots)


def generate(name: str, cache: Path) -> dict:
    path = cache / f"slot_ids_{name}.npz"
    if path.exists():
        z = np.load(path)
        return {k: z[k] for k in z.files}
    seeds, per_world, seed, crops = SETS[name]
    rng = np.random.default_rng(seed)
    jrng = np.random.default_rng(seed + 1000)
    presets = ("garage", "small")
    patches, labels, status, meta = [], [], [], []
    t0 = time.time()
    for ws in seeds:
        preset = presets[int(rng.integers(len(presets)))]
        world = make_world(preset, int(ws))
        if name == "letters":
            world = relabelled_world(world, rng)
        renderer = TopviewRenderer(world)
        captured = {}
        draw = renderer._draw_solids

        def capture(S, P, mTv, draw=draw, captured=captured):
            captured["polys"] = draw(S, P, mTv)
            return captured["polys"]

        renderer._draw_solids = capture
        n = renderer.spec.size_px
        for _ in range(per_world):
            mTv = random_aisle_pose(world, rng)
            rseed = int(rng.integers(2**31 - 1))
            image, _ = renderer.render(mTv, rseed)
            P = renderer._world_to_pixel(mTv)
            for i in renderer._near(renderer._label_boxes, mTv, 8.0):
                slot_id, label, _ = renderer._labels[i]
                box = renderer._apply(P, renderer._label_boxes[i])
                inside, visible, occluded = _label_status(box, captured["polys"], renderer._ego, n)
                if inside == 1.0 and occluded < 0.02:
                    st = READABLE
                elif visible < 0.15:
                    st = BLANK
                    c = box.mean(axis=0)
                    if c.min() < -30 or c.max() > n + 30 or jrng.random() < 0.6:
                        continue  # mostly off the image: keep a few, near the edge
                else:
                    continue
                corners = renderer._apply(P, np.asarray(world.slots[slot_id].corners, float))
                e = corners[:2]
                d = corners[3] - corners[0]
                d = d / np.hypot(*d)
                if np.abs(e.mean(axis=0) - n / 2).max() > n / 2 + 120:
                    continue  # the crop would be entirely off the image
                paint = world.slot_paint[slot_id]
                bottom, top = 0.35 + paint.text_height / 2, 0.35 + 1.5 * paint.text_height
                # camera samples across the text's height (the fisheye's resolution there)
                samples = paint.text_height / float(
                    renderer.source_spacing_m(box.mean(axis=0)[None])[0])
                for _c in range(crops):
                    ej, dj = _jittered(jrng, e, d)
                    ppm, rng_d = PX_PER_M, DEPTH_RANGE_M
                    if name.startswith("train"):  # the text anywhere in the patch, scaled
                        ppm *= jrng.uniform(0.8, 1.15)
                        span = (rng_d[1] - rng_d[0]) * PX_PER_M / ppm
                        lo = top + 0.05 - rng_d[0] - span
                        hi = bottom - 0.05 - rng_d[0]
                        shift = jrng.uniform(lo, max(lo, hi))
                        rng_d = (rng_d[0] + shift, rng_d[0] + shift + span)
                    patches.append(crop_id_patch(image, ej, dj, px_per_m=ppm, depth_range_m=rng_d))
                    labels.append(label if st == READABLE else "")
                    status.append(st)
                    meta.append((ws, rseed, slot_id, inside, visible, occluded, samples))
                if jrng.random() < (0.2 if name.startswith("train") else 0.1):  # the wrong way
                    ej, dj = _jittered(jrng, e, -d)
                    patches.append(crop_id_patch(image, ej, dj))
                    labels.append("")
                    status.append(BLANK)
                    meta.append((ws, rseed, slot_id, -1.0, 0.0, 0.0, samples))
        if ws % 50 == 0:
            print(
                f"[data {name}] world {ws}: {len(patches)} crops, {time.time() - t0:.0f} s",
                flush=True,
            )
    data = {
        "patches": np.stack(patches),
        "labels": np.array(labels, dtype="U4"),
        "status": np.array(status, np.int8),
        "meta": np.array(meta, float),
    }
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **data)
    return data


# ---------------------------------------------------------------- model


WIDTHS = (16, 32, 64, 96, 128, 128)
"""Channels of the four 2D conv blocks and the two 1D convs (``--widths``)."""


def parse_widths(text: str) -> tuple[int, ...]:
    """``--widths``: six positive integers, comma-separated."""
    try:
        widths = tuple(int(w) for w in text.split(","))
    except ValueError:
        widths = ()
    if len(widths) != 6 or min(widths) < 1:
        raise argparse.ArgumentTypeError(f"expected six positive integers, got {text!r}")
    return widths


def build_model(widths: tuple[int, ...] = WIDTHS):
    import torch
    from torch import nn

    c1, c2, c3, c4, s1, s2 = widths

    def block(i, o):
        return [nn.Conv2d(i, o, 3, padding=1, bias=False), nn.BatchNorm2d(o), nn.ReLU(inplace=True)]

    class Reader(nn.Module):
        def __init__(self):
            super().__init__()
            self.cnn = nn.Sequential(
                *block(1, c1),
                nn.MaxPool2d(2),  # 32 x 64
                *block(c1, c2),
                nn.MaxPool2d(2),  # 16 x 32
                *block(c2, c3),
                nn.MaxPool2d((2, 1)),  # 8 x 32
                *block(c3, c4),
            )
            self.seq = nn.Sequential(  # along the 32 columns (4 px each)
                nn.Conv1d(c4, s1, 5, padding=2, bias=False),
                nn.BatchNorm1d(s1),
                nn.ReLU(inplace=True),
                nn.Conv1d(s1, s2, 5, padding=2, bias=False),
                nn.BatchNorm1d(s2),
                nn.ReLU(inplace=True),
                nn.Conv1d(s2, len(ALPHABET) + 1, 1),
            )
            self.register_buffer("inv_temperature", torch.ones(()))

        def logits(self, x):
            """x: (N, 1, 64, 128) raw grey levels 0-255 -> (N, T, C) logits."""
            mean = x.mean(dim=(2, 3), keepdim=True)
            std = x.std(dim=(2, 3), keepdim=True)
            x = (x - mean) / (std + 8.0)
            f = self.cnn(x).amax(dim=2)  # (N, c4, 32): the text may sit at any height
            return self.seq(f).permute(0, 2, 1)  # (N, T, C)

        def forward(self, x):
            return torch.softmax(self.logits(x) * self.inv_temperature, dim=-1)

    return Reader()


def encode(labels):
    idx = {c: k + 1 for k, c in enumerate(ALPHABET)}
    flat = [idx[c] for s in labels for c in s]
    return flat, [len(s) for s in labels]


def augment(batch: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = np.empty(batch.shape, np.float32)
    h, w = batch.shape[1:]
    for k, p in enumerate(batch):
        x = p.astype(np.float32)
        if rng.random() < 0.5:  # blur
            x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.3, 1.4))
        if rng.random() < 0.3:  # motion-like anisotropic blur
            x = cv2.blur(x, (int(rng.integers(1, 5)), int(rng.integers(1, 4))))
        if rng.random() < 0.4:  # margin blobs (car shadows, wheels, stains)
            for _ in range(int(rng.integers(1, 3))):
                bw, bh = int(rng.integers(4, 20)), int(rng.integers(6, h))
                x0 = (
                    int(rng.integers(0, 24 - bw + 1))
                    if rng.random() < 0.5
                    else w - 24 + int(rng.integers(0, 24 - bw + 1))
                )
                y0 = int(rng.integers(0, h - bh + 1))
                x[y0 : y0 + bh, x0 : x0 + bw] = rng.uniform(0, 255)
        # gain map: brightness, contrast, a linear gradient
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
        grad = (
            1.0 + rng.uniform(-0.4, 0.4) * (gx / w - 0.5) + rng.uniform(-0.4, 0.4) * (gy / h - 0.5)
        )
        mean = x.mean()
        x = (x - mean) * rng.uniform(0.45, 1.4) + mean * rng.uniform(0.5, 1.5)
        x = x * grad
        if rng.random() < 0.3:
            x = 255.0 * (np.clip(x, 0, 255) / 255.0) ** rng.uniform(0.6, 1.6)
        x = x + rng.normal(0, rng.uniform(0, 12), x.shape)
        x = np.clip(x, 0, 255)
        if rng.random() < 0.4:
            ok, buf = cv2.imencode(
                ".jpg", x.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(25, 90))]
            )
            x = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE).astype(np.float32)
        out[k] = x
    return out


def train(
    data: dict,
    steps: int,
    batch: int,
    seed: int,
    minutes: float,
    lr_max: float = 2e-3,
    warmup: float = 0.03,
    init: Path | None = None,
    threads: int = 1,
    widths: tuple[int, ...] = WIDTHS,
):
    import torch

    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = build_model(widths)
    if init is not None:  # continue from a saved state dict (the optimiser starts afresh)
        model.load_state_dict(torch.load(init, map_location="cpu"))
        print(f"[train] initialised from {init}", flush=True)
    opt = torch.optim.AdamW(model.parameters(), lr=lr_max, weight_decay=1e-4)
    ctc = torch.nn.CTCLoss(blank=0, zero_infinity=True)
    X, Y = data["patches"], data["labels"]
    t0 = time.time()
    model.train()
    run = 0.0
    done = 0
    for step in range(steps):
        # schedule on progress = max(step share, wall-time share): warm-up, then cosine
        prog = max(step / steps, (time.time() - t0) / (minutes * 60))
        if prog >= 1.0:
            print(f"[train] time budget reached at step {step}", flush=True)
            break
        lr = lr_max * min(1.0, prog / warmup) * 0.5 * (1 + math.cos(math.pi * prog))
        for g in opt.param_groups:
            g["lr"] = lr
        done = step + 1
        idx = rng.integers(len(X), size=batch)
        xb = torch.from_numpy(augment(X[idx], rng))[:, None]
        flat, lens = encode(Y[idx])
        logp = torch.log_softmax(model.logits(xb), dim=-1).permute(1, 0, 2)  # (T, N, C)
        T = logp.shape[0]
        loss = ctc(
            logp,
            torch.tensor(flat, dtype=torch.long),
            torch.full((batch,), T, dtype=torch.long),
            torch.tensor(lens, dtype=torch.long),
        )
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
        opt.step()
        run = 0.98 * run + 0.02 * float(loss.detach()) if step else float(loss.detach())
        if step % 200 == 0 or step == steps - 1:
            el = time.time() - t0
            print(f"[train] step {step}/{steps} loss {run:.4f} lr {lr:.5f} {el:.0f} s", flush=True)
    model.eval()
    return model, time.time() - t0, done


# ---------------------------------------------------------------- calibration, evaluation


def predict_logits(model, patches: np.ndarray) -> np.ndarray:
    import torch

    out = []
    with torch.no_grad():
        for k in range(0, len(patches), 256):
            x = torch.from_numpy(patches[k : k + 256].astype(np.float32))[:, None]
            out.append(model.logits(x).numpy())
    return np.concatenate(out)


def readings(logits: np.ndarray, temperature: float):
    z = logits / temperature
    z = z - z.max(axis=-1, keepdims=True)
    p = np.exp(z)
    p /= p.sum(axis=-1, keepdims=True)
    return readings_from_probs(p)


def scores(reads, data):
    """(confidence, right) per crop: right = label matches (blank crops: None)."""
    conf = np.array([r.confidence for r in reads])
    right = np.array(
        [(r.label or "") == y for r, y in zip(reads, data["labels"], strict=True)], bool
    )
    return conf, right


def fit_temperature(logits, data, target: float = 0.998) -> float:
    best, best_nll = 1.0, np.inf
    for T in np.exp(np.linspace(math.log(0.5), math.log(4.0), 43)):
        conf, right = scores(readings(logits, T), data)
        c = np.clip(conf, 1e-6, 1 - 1e-6)
        nll = -np.mean(np.where(right, np.log(c), np.log(1 - c)))
        if nll < best_nll:
            best, best_nll = float(T), nll
    T = best
    for _ in range(40):  # then honest at the 0.9 threshold, with a margin: the labels
        # given there (what the mapper trusts), not the confident "nothing" readings
        reads = readings(logits, T)
        conf, right = scores(reads, data)
        hi = (conf >= 0.9) & np.array([r.label is not None for r in reads])
        if hi.sum() == 0 or right[hi].mean() >= target:
            break
        T *= 1.1
    return T


def evaluate(logits, data, T) -> dict:
    reads = readings(logits, T)
    conf, right = scores(reads, data)
    readable = data["status"] == READABLE
    blank = ~readable
    res = {
        "n_readable": int(readable.sum()),
        "accuracy_readable": float(right[readable].mean()),
        "n_blank": int(blank.sum()),
        "blank_read_as_none": float(right[blank].mean()),
    }
    for name, sel in (("readable", readable), ("all", np.ones(len(conf), bool))):
        hi = sel & (conf >= 0.9)
        res[f"{name}_share_conf_ge_0.9"] = float(hi.sum() / max(sel.sum(), 1))
        res[f"{name}_accuracy_conf_ge_0.9"] = float(right[hi].mean()) if hi.any() else None
        res[f"{name}_n_conf_ge_0.9"] = int(hi.sum())
    labelled = np.array([r.label is not None for r in reads])
    hi = labelled & (conf >= 0.9)
    res["labels_given_conf_ge_0.9_accuracy"] = float(right[hi].mean()) if hi.any() else None
    res["labels_given_conf_ge_0.9_n"] = int(hi.sum())
    table = []
    edges = [0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0001]
    for lo, up in zip(edges[:-1], edges[1:], strict=True):
        sel = (conf >= lo) & (conf < up)
        table.append(
            {
                "bin": f"[{lo:.2f}, {min(up, 1.0):.2f}]",
                "n": int(sel.sum()),
                "mean_conf": float(conf[sel].mean()) if sel.any() else None,
                "accuracy": float(right[sel].mean()) if sel.any() else None,
            }
        )
    res["reliability_all"] = table
    wrong = [
        (str(data["labels"][k]), reads[k].label, round(float(conf[k]), 3))
        for k in np.nonzero(~right)[0][:40]
    ]
    res["errors_sample"] = wrong
    return res


def evaluate_exported(path: Path, cache: Path) -> dict:
    """The exported model (temperature baked in) on the calibration and test crops, with
    the reader's confidence; ``extra_temperature`` is what the calibration rule would
    add on top (1.0: the baked one still holds)."""
    from semslam.perception.slot_ids import SlotIdReader

    reader = SlotIdReader(path, min_confidence=0.0)
    report: dict = {"model": str(path)}
    for name in ("calib", "test"):
        data = generate(name, cache)
        patches = data["patches"].astype(np.uint8)
        probs = np.concatenate(
            [reader.probabilities(patches[k : k + 256]) for k in range(0, len(patches), 256)]
        )
        log_probs = np.log(np.clip(probs, 1e-30, 1.0))
        if name == "calib":
            report["extra_temperature"] = fit_temperature(log_probs, data)
        report[name] = evaluate(log_probs, data, 1.0)
    return report


def export(model, T: float, out: Path) -> None:
    import torch

    model.inv_temperature.fill_(1.0 / T)
    x = torch.zeros(4, 1, PATCH_HEIGHT, PATCH_WIDTH)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        model,
        (x,),
        str(out),
        input_names=["patches"],
        output_names=["probs"],
        dynamic_axes={"patches": {0: "n"}, "probs": {0: "n"}},
        opset_version=17,
        dynamo=False,
    )


def time_onnx(path: Path, patches: np.ndarray) -> float:
    from semslam.perception.onnx_model import load_session

    sess = load_session(path)
    x = patches[:4].astype(np.float32)[:, None]
    for _ in range(10):
        sess.run(None, {"patches": x})
    t = []
    for _ in range(200):
        t0 = time.perf_counter()
        sess.run(None, {"patches": x})
        t.append(time.perf_counter() - t0)
    return float(np.median(t) * 1000)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("models/slot_ids.onnx"))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/slot_ids_cache"))
    ap.add_argument("--steps", type=int, default=6000, help="at most; see --minutes")
    ap.add_argument("--batch", type=int, default=48)
    ap.add_argument(
        "--minutes", type=float, default=24.0, help="training wall-time cap (the LR follows it)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lr", type=float, default=2e-3, help="peak learning rate")
    ap.add_argument("--warmup", type=float, default=0.03, help="warm-up share of the run")
    ap.add_argument("--init", type=Path, default=None, help="state dict to continue from")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1 on a shared machine)")
    ap.add_argument(
        "--train-sets", default="train", help="training sets, e.g. train,train2 (concatenated)"
    )
    ap.add_argument("--checkpoint", type=Path, default=None, help="where to save the state dict")
    ap.add_argument(
        "--stage",
        choices=("data", "all", "calibrate", "evaluate"),
        default="all",
        help="data: crops only; calibrate: no training, calibrate, test and export the "
        "--init weights; evaluate: the exported --out model on the calibration and "
        "test crops (an extra temperature fitted on top of the baked one is reported)",
    )
    ap.add_argument("--sets", default="train,calib,test")
    ap.add_argument(
        "--widths",
        type=parse_widths,
        default=WIDTHS,
        help="channels of the four 2D conv blocks and the two 1D convs, six integers",
    )
    ap.add_argument(
        "--calibration-target",
        type=float,
        default=0.998,
        help="labels at confidence >= 0.9 right at least this often on the calibration worlds",
    )
    ap.add_argument("--report", type=Path, default=Path("/tmp/slot_ids_report.json"))
    args = ap.parse_args()
    t0 = time.time()
    if args.stage == "data":
        data = {name: generate(name, args.cache) for name in args.sets.split(",")}
        sizes = ", ".join(f"{k}: {len(v['labels'])}" for k, v in data.items())
        print(f"[data] {sizes} in {time.time() - t0:.0f} s", flush=True)
        return
    if args.stage == "evaluate":
        report = evaluate_exported(args.out, args.cache)
        args.report.write_text(json.dumps(report, indent=1))
        print(json.dumps(report, indent=1))
        return
    import torch

    data = {}
    if args.stage == "calibrate":  # no training: calibrate, test and export --init
        if args.init is None:
            raise SystemExit("--stage calibrate needs --init (trained weights)")
        model = build_model(args.widths)
        model.load_state_dict(torch.load(args.init, map_location="cpu"))
        model.eval()
        train_s, done, n_train = 0.0, 0, 0
    else:
        parts = [generate(name, args.cache) for name in args.train_sets.split(",")]
        data["train"] = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        n_train = len(data["train"]["labels"])
        model, train_s, done = train(
            data["train"],
            args.steps,
            args.batch,
            args.seed,
            args.minutes,
            lr_max=args.lr,
            warmup=args.warmup,
            init=args.init,
            threads=args.threads,
            widths=args.widths,
        )
        torch.save(model.state_dict(), args.checkpoint or args.cache / "slot_ids.pt")
    data["calib"] = generate("calib", args.cache)
    data["test"] = generate("test", args.cache)
    cal_logits = predict_logits(model, data["calib"]["patches"])
    T = fit_temperature(cal_logits, data["calib"], args.calibration_target)
    report = {
        "train_seconds": train_s,
        "train_steps": done,
        "train_crops": n_train,
        "temperature": T,
        "calib": evaluate(cal_logits, data["calib"], T),
        "calib_T1": evaluate(cal_logits, data["calib"], 1.0),
    }
    test_logits = predict_logits(model, data["test"]["patches"])
    report["test"] = evaluate(test_logits, data["test"], T)
    export(model, T, args.out)
    report["onnx_bytes"] = args.out.stat().st_size
    report["onnx_ms_batch4"] = time_onnx(args.out, data["test"]["patches"])
    # the exported graph must agree with torch
    from semslam.perception.slot_ids import SlotIdReader

    reader = SlotIdReader(args.out, min_confidence=0.0)  # every label, as torch's readings
    onnx_reads = reader.read_patches(list(data["test"]["patches"][:200]))
    torch_reads = readings(test_logits[:200], T)
    report["onnx_torch_label_agreement"] = float(
        np.mean([a.label == b.label for a, b in zip(onnx_reads, torch_reads, strict=True)])
    )
    args.report.write_text(json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k != "calib_T1"}, indent=1))


if __name__ == "__main__":
    main()
