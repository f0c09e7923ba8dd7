"""A learned audio-to-face regressor as a peer: a small temporal convolutional network.

What the modern systems do (VOCA, FaceFormer, Audio2Face learn a network from audio features to
the face), kept small and honest so it can be trained per speaker on the same data and folds as
the voice puppet, on the CPU, in seconds: three 1-D convolutions (kernel 5, the second dilated
by 2: a context of ±6 frames) with 32 channels and ReLUs, from the same standardised audio
features the puppet's guide hears (:meth:`voicepuppet.puppet.model.Puppet.ridge_input`) to the
standardised face coordinates. Adam, mean squared error on mini-batches of eight random 64-frame
crops, weight decay 1e-4; early stopping on a validation share of the *training* sequences (a fifth, at least one),
keeping the weights with the lowest validation error. Fixed seed; one thread while training and
predicting, so the result does not depend on the machine's cores.

PyTorch is a test and benchmark dependency only (``pip install torch==2.13.0`` gives the CPU
build), imported when a model is made.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ConvRegressor", "torch_available"]


def torch_available() -> bool:
    """Whether PyTorch can be imported (the learned peer needs it).

    Returns
    -------
    bool
    """
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def _torch():
    try:
        import torch
    except ImportError:
        raise ImportError("the learned peer needs PyTorch (a test/benchmark dependency): "
                          "pip install torch==2.13.0 (the CPU build)") from None
    return torch


class _OneThread:
    """torch on one thread inside the block, as it was after."""

    def __enter__(self):
        torch = _torch()
        self.torch, self.before = torch, torch.get_num_threads()
        torch.set_num_threads(1)
        return torch

    def __exit__(self, *exc):
        self.torch.set_num_threads(self.before)
        return False


class ConvRegressor:
    """Temporal 1-D convolutional network from audio features to face coordinates.

    Parameters
    ----------
    channels : int
        Hidden channels (default 32).
    max_epochs : int
        Upper bound on training epochs (default 200); an epoch is about the training frames
        once, in mini-batches (at least four).
    patience : int
        Epochs without a better validation error before stopping (default 20).
    lr : float
        Adam's step size (default 3e-3).
    weight_decay : float
        Adam's weight decay (default 1e-4).
    crop : int
        Frames per training crop (default 64).
    batch : int
        Crops per mini-batch (default 8).
    seed : int
        Seeds the validation split, the weights and the crops (default 0).

    Attributes
    ----------
    epochs_ : int
        Epochs trained.
    best_epoch_ : int
        The epoch whose weights are kept.
    val_mse_ : float
        Their validation mean squared error (standardised face coordinates).
    """

    def __init__(self, *, channels: int = 32, max_epochs: int = 200, patience: int = 20, lr: float = 3e-3,
                 weight_decay: float = 1e-4, crop: int = 64, batch: int = 8, seed: int = 0):
        self.channels, self.max_epochs, self.patience = int(channels), int(max_epochs), int(patience)
        self.lr, self.weight_decay, self.seed = float(lr), float(weight_decay), int(seed)
        self.crop, self.batch = int(crop), int(batch)

    def _net(self, torch, n_in: int, n_out: int):
        nn, c = torch.nn, self.channels
        return nn.Sequential(nn.Conv1d(n_in, c, 5, padding=2), nn.ReLU(),
                             nn.Conv1d(c, c, 5, padding=4, dilation=2), nn.ReLU(),
                             nn.Conv1d(c, n_out, 1))

    def fit(self, X, Y) -> "ConvRegressor":
        """Train on sequences.

        Parameters
        ----------
        X : list of array, each (T_s, A)
            Standardised audio features per sequence.
        Y : list of array, each (T_s, K)
            Face coordinates per sequence (the same frames).

        Returns
        -------
        ConvRegressor
            self.

        Raises
        ------
        ValueError
            Fewer than two sequences (one is needed for early stopping), or shapes that differ.
        """
        X = [np.asarray(x, dtype=np.float32) for x in X]
        Y = [np.asarray(y, dtype=np.float64) for y in Y]
        if len(X) < 2 or len(X) != len(Y):
            raise ValueError(f"the learned peer needs two or more training sequences (one held for early "
                             f"stopping), as many features as faces; got {len(X)} and {len(Y)}")
        if any(x.ndim != 2 or y.ndim != 2 or len(x) != len(y) for x, y in zip(X, Y)) or \
                len({x.shape[1] for x in X}) != 1 or len({y.shape[1] for y in Y}) != 1:
            raise ValueError("X and Y must be (T_s, A) and (T_s, K) arrays of the same frames per sequence")
        Yall = np.vstack(Y)
        self.y_mean_, self.y_std_ = Yall.mean(axis=0), np.maximum(Yall.std(axis=0), 1e-12)
        Z = [((y - self.y_mean_) / self.y_std_).astype(np.float32) for y in Y]
        rng = np.random.default_rng(self.seed)
        order = rng.permutation(len(X))
        n_val = max(1, len(X) // 5)
        val, tr = order[:n_val], order[n_val:]
        with _OneThread() as torch:
            torch.manual_seed(self.seed)
            net = self._net(torch, X[0].shape[1], Z[0].shape[1])
            opt = torch.optim.Adam(net.parameters(), lr=self.lr, weight_decay=self.weight_decay)
            xv = [torch.from_numpy(X[i].T[None].copy()) for i in val]
            yv = [torch.from_numpy(Z[i].T[None].copy()) for i in val]
            frames = sum(len(X[i]) for i in tr)
            batches = max(4, -(-frames // (self.crop * self.batch)))  # about the training frames once
            best, best_state, since, epoch = np.inf, None, 0, 0
            for epoch in range(1, self.max_epochs + 1):
                net.train()
                for _ in range(batches):
                    xb, yb = self._crops(rng, [X[i] for i in tr], [Z[i] for i in tr], self.batch)
                    opt.zero_grad()
                    loss = torch.mean((net(torch.from_numpy(xb)) - torch.from_numpy(yb)) ** 2)
                    loss.backward()
                    opt.step()
                net.eval()
                with torch.no_grad():
                    v = float(sum(torch.sum((net(a) - b) ** 2) for a, b in zip(xv, yv))
                              / sum(b.numel() for b in yv))
                if v < best - 1e-6:
                    best, since, self.best_epoch_ = v, 0, epoch
                    best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
                else:
                    since += 1
                    if since >= self.patience:
                        break
            net.load_state_dict(best_state)
        self.net_, self.epochs_, self.val_mse_ = net, epoch, float(best)
        return self

    def _crops(self, rng, X, Z, n):
        """``n`` random crops of ``crop`` frames (shorter sequences padded with their edges)."""
        L = self.crop
        xb = np.empty((n, X[0].shape[1], L), np.float32)
        yb = np.empty((n, Z[0].shape[1], L), np.float32)
        lengths = np.array([len(x) for x in X], float)
        for j, s in enumerate(rng.choice(len(X), size=n, p=lengths / lengths.sum())):
            x, z = X[s], Z[s]
            if len(x) < L:
                x, z = np.pad(x, ((0, L - len(x)), (0, 0)), mode="edge"), np.pad(z, ((0, L - len(z)), (0, 0)), mode="edge")
            a = int(rng.integers(0, len(x) - L + 1))
            xb[j], yb[j] = x[a:a + L].T, z[a:a + L].T
        return xb, yb

    def predict(self, X) -> np.ndarray:
        """Face coordinates of one sequence.

        Parameters
        ----------
        X : array, shape (T, A)
            Standardised audio features.

        Returns
        -------
        ndarray, shape (T, K)
        """
        x = np.asarray(X, dtype=np.float32)
        with _OneThread() as torch:
            self.net_.eval()
            with torch.no_grad():
                z = self.net_(torch.from_numpy(x.T[None].copy()))[0].numpy().T.astype(np.float64)
        return z * self.y_std_ + self.y_mean_
