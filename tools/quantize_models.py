"""Quantize the marking-point grid pair to 8 bits (onnxruntime static quantization).

Each float grid model in ``semslam/models/`` (``tools/train_marking_points.py``'s output,
:data:`~semslam.perception.marking_points.FLOAT_MODELS`) gets an 8-bit twin,
``NAME.int8.onnx``, which the detector runs by default on a CPU with VNNI, and
``NAME.int8avx2.onnx`` with 7-bit weights (``reduce_range``), its default on a CPU with
AVX2 but no VNNI, where onnxruntime's 8-bit path would saturate with 8-bit weights. Both:
weights int8 per output channel,
activations uint8, the last convolution (the grid's heads) left in float. Activation
ranges: the 99.9999th percentile of what each layer sees in simulated top views of
training worlds 1000 .. 1000 + ``--worlds`` - 1 (never the benchmark's test worlds 0-99,
the validation worlds 100-149 nor a real image), shrunk to the input as the detector does.

These settings are the best of those measured (``BENCHMARKS.md``, "The grid pair in 8
bits"): the same points within a few of the 2,135 labelled on the held-out views, and 3-4
ms less per top view on this machine. The verifier and the ID reader stay float: in 8 bits
they were no faster, and the ID reader's confidences lost their calibration.

    PYTHONPATH=. python tools/quantize_models.py [--worlds 100] [--per-world 3]

Needs ``onnx`` (a training extra); the runtime loads the result with onnxruntime only.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

from semslam.perception import onnx_model
from semslam.perception.marking_points import (
    FLOAT_MODELS,
    INT8_AVX2_MODELS,
    INT8_MODELS,
    shrink,
)
from semslam.simulation.topview_samples import sample_topviews

CALIBRATION_WORLDS = 1000
"""First world seed of the calibration views: training worlds of the grid and ID models."""

PERCENTILE = 99.9999
"""Percentile of each activation's calibration values its 8-bit range covers."""


def calibration_views(worlds: int, per_world: int, size: int) -> list[np.ndarray]:
    """(1, size, size, 3) uint8 inputs: simulated top views shrunk as the detector does."""
    return [
        np.ascontiguousarray(shrink(sample.image, size))[None]
        for sample in sample_topviews(
            range(CALIBRATION_WORLDS, CALIBRATION_WORLDS + worlds), per_world, seed=20261128
        )
    ]


def quantize(src: Path, dst: Path, batches: list[np.ndarray], reduce_range: bool = False) -> None:
    """Static 8-bit quantization of ``src`` calibrated on ``batches``, written to ``dst``;
    ``reduce_range``: 7-bit weights, whose sums AVX2's ``vpmaddubsw`` cannot saturate."""
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    input_name = onnx_model.load_session(src).get_inputs()[0].name
    weighted = [n.name for n in onnx.load(str(src)).graph.node if n.op_type in ("Conv", "Gemm")]

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self._it = iter(batches)

        def get_next(self):
            x = next(self._it, None)
            return None if x is None else {input_name: x}

    fd, tmp = tempfile.mkstemp(suffix=".onnx", dir=dst.parent)
    os.close(fd)
    try:
        quantize_static(
            str(src),
            tmp,
            Reader(),
            quant_format=QuantFormat.QOperator,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            calibrate_method=CalibrationMethod.Percentile,
            nodes_to_exclude=weighted[-1:],
            extra_options={"CalibPercentile": PERCENTILE},
            reduce_range=reduce_range,
        )
        os.chmod(tmp, 0o644)
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=100)
    parser.add_argument("--per-world", type=int, default=3)
    args = parser.parse_args()
    grid_input = onnx_model.load_session(onnx_model.model_path(FLOAT_MODELS[0])).get_inputs()[0]
    views = calibration_views(args.worlds, args.per_world, int(grid_input.shape[1]))
    for twins, reduce_range in ((INT8_MODELS, False), (INT8_AVX2_MODELS, True)):
        for name, twin in zip(FLOAT_MODELS, twins, strict=True):
            src = onnx_model.model_path(name)
            dst = src.with_name(twin)
            quantize(src, dst, views, reduce_range)
            print(f"{dst.name}: calibrated on {len(views)} views, "
                  f"{src.stat().st_size / 1e6:.2f} -> {dst.stat().st_size / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
