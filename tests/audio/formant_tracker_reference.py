"""The online formant tracker in numpy: the oracle of the C++ ``voicepuppet::FormantTracker``
(audio_features.hpp) in its bounded-wait mode (``formant_lag``), which has no offline
counterpart. This is the Python streaming front end's tracker as it was before the port to C++
(moved here; used by tests only).
"""

import numpy as np


class FormantTrackerReference:
    """Online version of ``lpc.track_formants`` (same costs, same tie-breaking).

    Frames become final when every surviving path agrees on them (then the offline Viterbi
    path agrees too), and gap frames (chosen assignment invalid) once the next valid frame is
    final (linear interpolation, as ``np.interp``). ``max_delay`` (frames, or None) forces a
    decision for frames pending longer than that.
    """

    def __init__(self, n_formants: int, ceiling: float, n_cand: int, max_delay: int | None):
        from itertools import combinations

        from voicepuppet.audio.lpc import reference_formants

        self.n = n_formants
        self.ref = reference_formants(ceiling, n_formants)
        self.combos = np.array(list(combinations(range(n_cand), n_formants)), dtype=np.int64)
        self.S = self.combos.shape[0]
        self.max_delay = max_delay
        self.score = None
        self.t = 0              # frames pushed
        self.base = 0           # global frame index of pending[0]
        self.F, self.valid, self.back = [], [], []  # per pending frame (from base)
        self.prev_logF = self.prev_valid = None
        # decided assignments awaiting output: (frame, values or None for a gap frame)
        self.decided: list = []
        self.out_next = 0       # next frame to output
        self.last_good = None   # (frame, values) of the last valid decided frame
        self.any_good = False
        self.forced = 0         # frames whose output was forced by max_delay

    def push(self, freqs: np.ndarray, bands: np.ndarray) -> list:
        """Candidates of new frames (K, n_cand) each; returns finished rows [(n,), ...]."""
        out = []
        for f, b in zip(freqs, bands):
            self._step(f, b)
            self._decide_converged()
            out += self._emit(final=False)
        return out

    def _step(self, f, b):
        F = f[self.combos]      # (S, n)
        B = b[self.combos]
        valid = np.all(np.isfinite(F), axis=1)
        with np.errstate(invalid="ignore"):
            local = 1.0 * np.sum(np.abs(F - self.ref) / self.ref, axis=1) + \
                1.0 * np.sum(B / F, axis=1)
        local = np.where(valid, local, 1e6)
        logF = np.log(np.where(np.isfinite(F), F, 1.0))
        if self.score is None:
            self.score = local.copy()
            back = np.zeros(self.S, dtype=np.int64)
        else:
            trans = 1.0 * np.sum(np.abs(logF[None, :, :] - self.prev_logF[:, None, :]), axis=2)
            both = self.prev_valid[:, None] & valid[None, :]
            trans = np.where(both, trans, 0.0)
            tot = self.score[:, None] + trans
            back = np.argmin(tot, axis=0)
            self.score = tot[back, np.arange(self.S)] + local
        self.prev_logF, self.prev_valid = logF, valid
        self.F.append(F)
        self.valid.append(valid)
        self.back.append(back)
        self.t += 1

    def _trace(self, end_states):
        """Backtrack from states at the last pushed frame; returns paths (len(pending), k)."""
        P = len(self.back)
        paths = np.empty((P, len(end_states)), dtype=np.int64)
        cur = np.asarray(end_states, dtype=np.int64)
        paths[-1] = cur
        for i in range(P - 1, 0, -1):
            cur = self.back[i][cur]
            paths[i - 1] = cur
        return paths

    def _commit(self, states):
        """Pending frames 0 .. len(states) - 1 take `states`; drop them from pending."""
        for i, s in enumerate(states):
            good = bool(self.valid[i][s])
            self.decided.append((self.base + i, self.F[i][s].copy() if good else None))
        k = len(states)
        del self.F[:k], self.valid[:k], self.back[:k]
        self.base += k

    def _decide_converged(self):
        if len(self.back) <= 1:
            return
        paths = self._trace(np.arange(self.S))
        same = np.all(paths == paths[:, :1], axis=1)
        # frames 0 .. u all agree (agreement at u implies agreement before u)
        nz = np.nonzero(same)[0]
        if nz.shape[0] == 0:
            return
        u = int(nz[-1])
        if u < len(self.back) - 1:
            self._commit(paths[:u + 1, 0])
        # the last pending frame stays (its back pointers are needed for the next frame)

    def _emit(self, final: bool) -> list:
        out = []
        while self.decided:
            frame, val = self.decided[0]
            if frame != self.out_next:
                raise AssertionError("formant tracker out of order")  # a bug
            if val is not None:
                self._fill_gap_to(frame, val, out)
                out.append(val)
                self.last_good = (frame, val)
                self.any_good = True
                self.decided.pop(0)
                self.out_next += 1
                continue
            # a gap frame: needs the next good frame (or the end of the stream)
            nxt = next((d for d in self.decided if d[1] is not None), None)
            if nxt is not None:
                self._fill_gap_to(nxt[0], nxt[1], out)
                continue
            if final:
                self.decided.pop(0)
                out.append(self.last_good[1].copy() if self.last_good is not None
                           else None)  # None: no good frame at all (resolved by caller)
                self.out_next += 1
                continue
            if self.max_delay is not None and self.t - 1 - frame >= self.max_delay:
                self.decided.pop(0)
                out.append(self.last_good[1].copy() if self.last_good is not None
                           else self.ref.copy())
                self.forced += 1
                self.out_next += 1
                continue
            break
        return out

    def _fill_gap_to(self, frame, val, out):
        """Emit the decided gap frames before `frame` (a good frame with values `val`)."""
        while self.decided and self.decided[0][0] < frame:
            g, _ = self.decided.pop(0)
            if self.last_good is None:
                out.append(val.copy())  # leading gap: np.interp holds the first value
            else:
                x0, f0 = self.last_good
                out.append(np.array([np.interp(g, [x0, frame], [f0[i], val[i]])
                                     for i in range(self.n)]))
            self.out_next += 1

    def force(self):
        """Apply max_delay to frames still on undecided paths."""
        if self.max_delay is None or not self.back:
            return []
        if self.t - 1 - self.base < self.max_delay:
            return []
        # decide the frames that have waited max_delay frames, from the current best path
        # (the last frame too when max_delay is 0: later tracebacks stop at the decided frames)
        paths = self._trace([int(np.argmin(self.score))])[:, 0]
        k = min(len(paths), (self.t - 1 - self.max_delay) - self.base + 1)
        if k <= 0:
            return []
        self.forced += k
        self._commit(paths[:k])
        return self._emit(final=False)

    def finish(self) -> list:
        """End of stream: the best path from the last frame decides the rest."""
        out = []
        if self.back:
            paths = self._trace([int(np.argmin(self.score))])[:, 0]
            self._commit(paths)
        rows = self._emit(final=True)
        if rows and any(r is None for r in rows):
            if self.any_good:
                raise AssertionError("formant tracker: gap without a good frame")  # a bug
            rows = [self.ref.copy() for _ in rows]
        out += rows
        return out
