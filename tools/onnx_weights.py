"""Fine-tuning a shipped ONNX file: its weights back into the training script's torch net.

The exporter folds each batch norm into the convolution before it, so the file holds
convolutions with biases and fully connected (Gemm) layers only. :func:`load_folded_onnx`
gives each convolution of the net the folded weight and turns its batch norm into the
identity plus the folded bias (mean 0, variance 1 - eps, scale 1); with
:func:`freeze_batch_norms` called after each ``net.train()`` the net computes the file's
function while it is fine-tuned (the batch norms' scale and bias still learn, their
statistics do not move). torch and onnx are training extras, as in the scripts.
"""

from __future__ import annotations

from pathlib import Path


def load_folded_onnx(net, path: Path) -> None:
    """Load ``path``'s weights into ``net`` (an ``nn.Sequential`` of the architecture the
    file was exported from): convolutions and linear layers in graph order."""
    import onnx
    import torch
    import torch.nn as nn
    from onnx import numpy_helper

    model = onnx.load(str(path))
    weights = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    nodes = [n for n in model.graph.node if n.op_type in ("Conv", "Gemm")]
    mods = list(net)
    layers = [m for m in mods if isinstance(m, (nn.Conv2d, nn.Linear))]
    kinds = [("Conv" if isinstance(m, nn.Conv2d) else "Gemm") for m in layers]
    if [n.op_type for n in nodes] != kinds:
        raise SystemExit(f"{path}: layers {[n.op_type for n in nodes]}, the net has {kinds}")
    with torch.no_grad():
        for node, layer in zip(nodes, layers, strict=True):
            w, b = (torch.from_numpy(weights[name].copy()) for name in node.input[1:3])
            if w.shape != layer.weight.shape:
                raise SystemExit(f"{path}: {node.input[1]} is {tuple(w.shape)}, the net's "
                                 f"layer {tuple(layer.weight.shape)}")
            layer.weight.copy_(w)
            k = mods.index(layer) + 1
            after = mods[k] if k < len(mods) else None
            if isinstance(after, nn.BatchNorm2d):
                after.weight.fill_(1.0)
                after.bias.copy_(b)
                after.running_mean.zero_()
                after.running_var.fill_(1.0 - after.eps)
            else:
                layer.bias.copy_(b)


def freeze_batch_norms(net) -> None:
    """Batch norms in eval mode: their running statistics kept (scale and bias still learn)."""
    import torch.nn as nn

    for m in net.modules():
        if isinstance(m, nn.BatchNorm2d):
            m.eval()
