"""Planted data shared by tests of several stages (importable from any test: pytest puts the
folder of the root conftest.py on the path)."""

import numpy as np

FPS = 25.0
RATE = 16000
TONES = (220.0, 700.0, 1800.0)


def performance(rng, T):
    """Landmarks of a 10-point face making one of three shapes, and audio: a tone per shape."""
    P = 10
    ang = np.linspace(0, 2 * np.pi, P, endpoint=False)
    base = np.stack([np.cos(ang), np.sin(ang)], axis=1) * 40 + 120
    jaw = np.zeros((P, 2))
    jaw[2, 1] = 20.0
    shapes = np.stack([base, base + jaw, base * [0.7, 1.0] + [36, 0]])
    states = np.repeat(rng.integers(0, 3, T // 10 + 1), 10)[:T]
    pts = shapes[states] + rng.normal(0, 0.2, (T, P, 2))
    n = int(round(T / FPS * RATE))
    t = np.arange(n) / RATE
    frame_state = states[np.minimum((t * FPS).astype(int), T - 1)]
    audio = 0.3 * np.sin(2 * np.pi * np.asarray(TONES)[frame_state] * t) + 0.003 * rng.normal(size=n)
    return pts, audio, states


def planted_puppet_data(rng, T=900, P=12):
    """Three facial states (rest, open, round) visited in runs; the audio says which one. The
    world (shapes, audio means) is fixed; ``rng`` draws the sequence and the noise."""
    world = np.random.default_rng(1)
    base = np.stack([np.cos(np.linspace(0, 2 * np.pi, P, endpoint=False)),
                     np.sin(np.linspace(0, 2 * np.pi, P, endpoint=False))], axis=1) * 50 + 160
    modes = np.zeros((3, P, 2))
    modes[1, P // 4, 1] = 25.0       # one point drops (jaw open)
    modes[2, :, 0] = (base[:, 0] - 160) * -0.3  # narrow (rounding)
    states = np.repeat(rng.integers(0, 3, T // 15), 15)[:T]
    shape = base + modes[states] + rng.normal(0, 0.3, (T, P, 2))
    # Smooth the switches a little, as faces do.
    k = np.array([0.25, 0.5, 0.25])
    shape = np.apply_along_axis(lambda v: np.convolve(np.pad(v, 1, mode="edge"), k, "valid"), 0, shape)
    audio_means = world.normal(0, 3, (3, 5))
    feats = audio_means[states] + rng.normal(0, 1.0, (T, 5))
    return shape, feats, states
