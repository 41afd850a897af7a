"""A small convolutional network trained from scratch on the CPU, with PyTorch.

The full-hand paper fine-tunes ImageNet networks (InceptionNetV3: 98.28 % from one capture);
no pretrained weights can be downloaded here. A LeNet-like network on the downsampled
difference images needs none: two 3x3 convolutions (zero padding 1), ReLU, 2x2 max pooling and
a dense softmax layer, trained by mini-batch SGD with momentum on the cross-entropy (PyTorch's
layers, autograd and optimiser; ``torch`` is pinned to its CPU build, docs/recognition.md says
what it costs).

Training follows the paper's Table 5 where it applies: 30 epochs, batch 8, momentum 0.9,
learning rate dropped by 0.1 every 8 epochs, initial rate 0.01 (its Table 6 value for
InceptionNetV3); plus an L2 weight decay of 1e-4 on the weights, not the biases (assumed).
Weights start He-normal (the dense layer's with variance 1/fan-in), biases at zero.

Deterministic for a given seed: the initialisation is drawn from a ``torch.Generator`` seeded
with it and the batch order from a NumPy generator seeded with it; training and prediction run
on one thread with ``torch.use_deterministic_algorithms`` (both restored afterwards).

Layout: images are (n, h, w) float, fed as (n, 1, h, w) float32.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import torch
from torch import nn


@contextmanager
def _deterministic_one_thread():
    """One thread and deterministic kernels inside, the caller's settings restored after."""
    threads = torch.get_num_threads()
    was = torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(was)
        torch.set_num_threads(threads)


def _seed(rng) -> int:
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(2**63 - 1))
    if isinstance(rng, bool) or not isinstance(rng, int | np.integer) or rng < 0:
        raise ValueError(f"rng={rng!r}: give a seed (an integer >= 0) or a numpy Generator")
    return int(rng)


class SmallCNN:
    """conv3x3(1->c1) ReLU pool2 -> conv3x3(c1->c2) ReLU pool2 -> dense -> softmax.

    Parameters
    ----------
    n_classes : output classes (>= 2)
    input_shape : (h, w), both positive multiples of 4
    channels : (c1, c2)
    rng : seed (integer >= 0) or numpy Generator (initialisation; batch order)

    Attributes
    ----------
    net : the ``torch.nn.Sequential``
    scale_ : the training images' standard deviation (inputs are divided by it)
    history_ : mean training loss of each epoch (after :meth:`fit`)
    """

    def __init__(self, n_classes: int, input_shape: tuple[int, int], *,
                 channels: tuple[int, int] = (8, 16), rng=0) -> None:
        h, w = (int(v) for v in input_shape)
        if h % 4 or w % 4 or h < 4 or w < 4:
            raise ValueError(f"input_shape={input_shape!r}: height and width must be "
                             "positive multiples of 4 (two 2x2 poolings)")
        if n_classes < 2:
            raise ValueError(f"n_classes={n_classes}: need at least 2")
        self.n_classes = int(n_classes)
        self.input_shape = (h, w)
        self.channels = tuple(int(c) for c in channels)
        if len(self.channels) != 2 or min(self.channels) < 1:
            raise ValueError(f"channels={channels!r}: give two positive channel counts")
        seed = _seed(rng)
        self.rng = np.random.default_rng(seed)
        c1, c2 = self.channels
        self.net = nn.Sequential(
            nn.Conv2d(1, c1, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(c1, c2, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Flatten(), nn.Linear(h // 4 * w // 4 * c2, self.n_classes))
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            for layer in self.net:
                if isinstance(layer, nn.Conv2d | nn.Linear):
                    fan_in = layer.weight[0].numel()
                    gain = 2.0 if isinstance(layer, nn.Conv2d) else 1.0  # He; dense: 1/fan-in
                    nn.init.normal_(layer.weight, 0.0, float(np.sqrt(gain / fan_in)),
                                    generator=gen)
                    nn.init.zeros_(layer.bias)
        self.scale_ = 1.0

    def _tensor(self, images: np.ndarray) -> torch.Tensor:
        x = np.asarray(images, dtype=float)
        if x.ndim != 3 or x.shape[1:] != self.input_shape:
            raise ValueError(f"images of shape {x.shape[1:]} do not match input_shape="
                             f"{self.input_shape}")
        return torch.from_numpy((x / self.scale_).astype(np.float32)[:, None])

    # -- training -------------------------------------------------------------------------
    def fit(self, images: np.ndarray, y: np.ndarray, *, epochs: int = 30, batch: int = 8,
            lr: float = 0.01, momentum: float = 0.9, drop_every: int = 8, drop: float = 0.1,
            weight_decay: float = 1e-4, progress: bool = False) -> SmallCNN:
        """Train on ``images`` (n, h, w) with labels ``y`` (n,) in 0..n_classes-1 (module
        docstring)."""
        for name, v in (("epochs", epochs), ("batch", batch)):
            if v < 1:
                raise ValueError(f"{name}={v} is out of range: allowed >= 1")
        y = np.asarray(y, dtype=np.int64)
        x_np = np.asarray(images, dtype=float)
        if len(y) != len(x_np) or len(y) == 0:
            raise ValueError(f"{len(x_np)} images and {len(y)} labels: need as many, at least 1")
        if y.min() < 0 or y.max() >= self.n_classes:
            raise ValueError(f"labels y span {y.min()}..{y.max()}: allowed 0.."
                             f"{self.n_classes - 1}")
        self.scale_ = float(np.std(x_np)) or 1.0
        x = self._tensor(x_np)
        labels = torch.from_numpy(y)
        weights = [p for n, p in self.net.named_parameters() if n.endswith("weight")]
        biases = [p for n, p in self.net.named_parameters() if n.endswith("bias")]
        opt = torch.optim.SGD([{"params": weights, "weight_decay": weight_decay},
                               {"params": biases, "weight_decay": 0.0}],
                              lr=lr, momentum=momentum)
        sched = (torch.optim.lr_scheduler.StepLR(opt, drop_every, drop) if drop_every
                 else None)
        loss_fn = nn.CrossEntropyLoss()
        self.history_ = []
        from tqdm import tqdm

        with _deterministic_one_thread():
            self.net.train()
            for _ in tqdm(range(epochs), desc="CNN epochs", disable=not progress,
                          leave=False):
                order = torch.from_numpy(self.rng.permutation(len(x)))
                total = 0.0
                for s in range(0, len(x), batch):
                    idx = order[s:s + batch]
                    opt.zero_grad()
                    loss = loss_fn(self.net(x[idx]), labels[idx])
                    loss.backward()
                    opt.step()
                    total += loss.item() * len(idx)
                if sched is not None:
                    sched.step()
                self.history_.append(total / len(x))
        return self

    def predict_proba(self, images: np.ndarray, *, batch: int = 256) -> np.ndarray:
        """(n, n_classes) softmax probabilities (float64)."""
        x = self._tensor(images)
        out = []
        with _deterministic_one_thread(), torch.no_grad():
            self.net.eval()
            for s in range(0, len(x), batch):
                logits = self.net(x[s:s + batch]).double()  # (no float32 underflow to 0)
                out.append(torch.softmax(logits, dim=1).numpy())
        return np.concatenate(out) if out else np.zeros((0, self.n_classes))


__all__ = ["SmallCNN"]
