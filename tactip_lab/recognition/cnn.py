"""A small convolutional network written with NumPy, trained from scratch on the CPU.

The full-hand paper fine-tunes ImageNet networks (InceptionNetV3: 98.28 % from one capture);
no pretrained weights can be downloaded here, and PyTorch would add about 700 MB to the
project's install for one study. A LeNet-like network on the downsampled difference images
needs neither: two 3x3 convolutions (im2col, one matrix product each), ReLU, 2x2 max pooling
and a dense softmax layer, trained by mini-batch SGD with momentum on the cross-entropy. Its
gradients are checked against finite differences in the tests.

Training follows the paper's Table 5 where it applies: 30 epochs, batch 8, momentum 0.9,
learning rate dropped by 0.1 every 8 epochs, initial rate 0.01 (its Table 6 value for
InceptionNetV3); plus an L2 weight decay of 1e-4 (assumed). Deterministic for a given seed
(initialisation and batch order from one generator).

Layout: images are (n, h, w) float; activations channels-last (n, h, w, c).
"""

from __future__ import annotations

import numpy as np


def _im2col(x: np.ndarray) -> np.ndarray:
    """(n, h, w, c) -> (n, h, w, c*9) 3x3 neighbourhoods (zero padding 1)."""
    n, h, w, c = x.shape
    xp = np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
    win = np.lib.stride_tricks.sliding_window_view(xp, (3, 3), axis=(1, 2))  # n,h,w,c,3,3
    return win.reshape(n, h, w, c * 9)


def _col2im(dcols: np.ndarray, c: int) -> np.ndarray:
    """Adjoint of :func:`_im2col`: (n, h, w, c*9) -> (n, h, w, c)."""
    n, h, w, _ = dcols.shape
    d = dcols.reshape(n, h, w, c, 3, 3)
    dxp = np.zeros((n, h + 2, w + 2, c), dtype=dcols.dtype)
    for i in range(3):
        for j in range(3):
            dxp[:, i:i + h, j:j + w, :] += d[..., i, j]
    return dxp[:, 1:-1, 1:-1, :]


def _pool(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2x2 max pooling (h, w even): output and the argmax mask (first maximum only)."""
    n, h, w, c = x.shape
    r = x.reshape(n, h // 2, 2, w // 2, 2, c).transpose(0, 1, 3, 5, 2, 4).reshape(
        n, h // 2, w // 2, c, 4)
    k = r.argmax(axis=4)
    mask = np.zeros_like(r, dtype=bool)
    np.put_along_axis(mask, k[..., None], True, axis=4)
    return np.take_along_axis(r, k[..., None], axis=4)[..., 0], mask


def _unpool(d: np.ndarray, mask: np.ndarray) -> np.ndarray:
    n, h2, w2, c = d.shape
    r = mask * d[..., None]
    return r.reshape(n, h2, w2, c, 2, 2).transpose(0, 1, 4, 2, 5, 3).reshape(
        n, 2 * h2, 2 * w2, c)


class SmallCNN:
    """conv3x3(1->c1) ReLU pool2 -> conv3x3(c1->c2) ReLU pool2 -> dense -> softmax.

    Parameters
    ----------
    n_classes : output classes
    input_shape : (h, w), both divisible by 4
    channels : (c1, c2)
    rng : seed or Generator (He initialisation; batch order)
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
        self.rng = np.random.default_rng(rng)
        c1, c2 = self.channels
        r = self.rng
        self.params = {
            "w1": r.normal(0, np.sqrt(2 / 9), (9, c1)), "b1": np.zeros(c1),
            "w2": r.normal(0, np.sqrt(2 / (9 * c1)), (9 * c1, c2)), "b2": np.zeros(c2),
            "w3": r.normal(0, np.sqrt(1 / (h // 4 * w // 4 * c2)),
                           (h // 4 * w // 4 * c2, self.n_classes)),
            "b3": np.zeros(self.n_classes),
        }
        self.scale_ = 1.0

    # -- forward / backward ---------------------------------------------------------------
    def _forward(self, x: np.ndarray):
        p = self.params
        x = x[..., None]
        cols1 = _im2col(x)
        z1 = cols1 @ p["w1"] + p["b1"]
        a1 = np.maximum(z1, 0)
        q1, m1 = _pool(a1)
        cols2 = _im2col(q1)
        z2 = cols2 @ p["w2"] + p["b2"]
        a2 = np.maximum(z2, 0)
        q2, m2 = _pool(a2)
        flat = q2.reshape(len(x), -1)
        logits = flat @ p["w3"] + p["b3"]
        return logits, (cols1, z1, m1, q1, cols2, z2, m2, q2, flat)

    def loss_and_grads(self, x: np.ndarray, y: np.ndarray, weight_decay: float = 0.0
                       ) -> tuple[float, dict[str, np.ndarray]]:
        """Mean cross-entropy (+ L2) of images ``x`` (n, h, w), labels ``y`` (n,), and the
        gradient of every parameter."""
        p = self.params
        n = len(x)
        logits, (cols1, z1, m1, q1, cols2, z2, m2, q2, flat) = self._forward(x)
        logits = logits - logits.max(axis=1, keepdims=True)
        prob = np.exp(logits)
        prob /= prob.sum(axis=1, keepdims=True)
        loss = -np.mean(np.log(np.maximum(prob[np.arange(n), y], 1e-300)))
        loss += 0.5 * weight_decay * sum(np.sum(p[k] ** 2) for k in ("w1", "w2", "w3"))
        d = prob
        d[np.arange(n), y] -= 1.0
        d /= n
        g = {"w3": flat.T @ d, "b3": d.sum(axis=0)}
        dq2 = (d @ p["w3"].T).reshape(q2.shape)
        dz2 = _unpool(dq2, m2) * (z2 > 0)
        g["w2"] = cols2.reshape(-1, cols2.shape[-1]).T @ dz2.reshape(-1, dz2.shape[-1])
        g["b2"] = dz2.sum(axis=(0, 1, 2))
        dq1 = _col2im(dz2 @ p["w2"].T, q1.shape[-1])
        dz1 = _unpool(dq1, m1) * (z1 > 0)
        g["w1"] = cols1.reshape(-1, 9).T @ dz1.reshape(-1, dz1.shape[-1])
        g["b1"] = dz1.sum(axis=(0, 1, 2))
        for k in ("w1", "w2", "w3"):
            g[k] = g[k] + weight_decay * p[k]
        return float(loss), g

    # -- training -------------------------------------------------------------------------
    def fit(self, images: np.ndarray, y: np.ndarray, *, epochs: int = 30, batch: int = 8,
            lr: float = 0.01, momentum: float = 0.9, drop_every: int = 8, drop: float = 0.1,
            weight_decay: float = 1e-4, progress: bool = False) -> SmallCNN:
        """Train on ``images`` (n, h, w) with labels ``y`` (n,) (module docstring)."""
        x = np.asarray(images, dtype=float)
        if x.shape[1:] != self.input_shape:
            raise ValueError(f"images of shape {x.shape[1:]} do not match input_shape="
                             f"{self.input_shape}")
        for name, v in (("epochs", epochs), ("batch", batch)):
            if v < 1:
                raise ValueError(f"{name}={v} is out of range: allowed >= 1")
        y = np.asarray(y, dtype=np.int64)
        self.scale_ = float(np.std(x)) or 1.0
        x = x / self.scale_
        vel = {k: np.zeros_like(v) for k, v in self.params.items()}
        self.history_ = []
        from tqdm import tqdm

        for epoch in tqdm(range(epochs), desc="CNN epochs", disable=not progress,
                          leave=False):
            rate = lr * drop ** (epoch // drop_every) if drop_every else lr
            order = self.rng.permutation(len(x))
            total = 0.0
            for s in range(0, len(x), batch):
                idx = order[s:s + batch]
                loss, g = self.loss_and_grads(x[idx], y[idx], weight_decay)
                total += loss * len(idx)
                for k in self.params:
                    vel[k] = momentum * vel[k] - rate * g[k]
                    self.params[k] += vel[k]
            self.history_.append(total / len(x))
        return self

    def predict_proba(self, images: np.ndarray, *, batch: int = 256) -> np.ndarray:
        """(n, n_classes) softmax probabilities."""
        x = np.asarray(images, dtype=float) / self.scale_
        out = []
        for s in range(0, len(x), batch):
            logits, _ = self._forward(x[s:s + batch])
            logits -= logits.max(axis=1, keepdims=True)
            p = np.exp(logits)
            out.append(p / p.sum(axis=1, keepdims=True))
        return np.concatenate(out) if out else np.zeros((0, self.n_classes))


__all__ = ["SmallCNN"]
