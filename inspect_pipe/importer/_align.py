"""The camera's clock against the flight log's, from the footage itself.

Image motion: each pair of consecutive frames is registered by phase correlation
(``cv2.phaseCorrelate`` on quarter-size grey frames with a Hann window), giving how far the image
moved (dx, dy px) between the two instants. Log motion over the same two instants, for a trial
offset ``L`` (camera time minus log time), read at ``t - L``: the vehicle's displacement in body
axes (logged velocity at mid-interval, turned by the attitude, times the interval) and its rotation
vector (relative attitude). Whatever the camera's mounting (forward, down, gimballed still), the
image shift is close to a linear function of these six numbers (translation scaled by focal length
over range, rotation by focal length), so for each ``L`` (dx, dy) is regressed on them (least
squares with an intercept) and the multiple correlation ``r`` (square root of the joint R²) is the
score. Signed components matter: a lawnmower's passes at one speed differ only in direction. ``L`` is searched over the whole flight on a 50 ms grid (±10 s
when both clocks are UTC; everywhere the footage fits inside the log otherwise), then on a 2 ms
grid around the best, then refined to the vertex of a parabola through the peak.

``confidence`` = R² at the peak x (1 - unexplained variance at the peak / unexplained variance at
the best other local maximum more than 0.5 s away): near 0 when two offsets explain the motion
equally well or when the motion is not explained at all, near 1 when one offset explains it and
no other comes close.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from inspect_pipe.importer._logs import FlightTrack

__all__ = ["Alignment", "image_motion", "find_offset", "interp_pos", "interp_quat"]

METHOD = "image_motion_xcorr"
MAX_PAIR_GAP_S = 1.5  # frames further apart are not paired (interval shooting at 1 Hz still is)


@dataclass(frozen=True)
class Alignment:
    camera_clock_offset_s: float  # camera time minus log time (both UTC when the log has UTC)
    method: str
    confidence: float | None
    correlation: float | None = None
    second_peak: float | None = None
    pairs: int = 0
    searched_s: tuple[float, float] | None = None

    def to_json(self) -> dict:
        d = {"camera_clock_offset_s": round(self.camera_clock_offset_s, 4), "method": self.method,
             "confidence": None if self.confidence is None else round(self.confidence, 3)}
        if self.method == METHOD:
            d.update({"correlation": round(self.correlation or 0.0, 4), "second_peak": round(self.second_peak or 0.0, 4),
                      "frame_pairs": self.pairs, "searched_s": [round(v, 3) for v in (self.searched_s or (0, 0))]})
        return d


def image_motion(images, times: list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t0, t1, shift px) per consecutive pair, from an iterator of grey images; shift is NaN
    where the registration is not trusted (response < 0.05) or frames are far apart in time."""
    prev = None
    window = None
    t0s, t1s, shifts = [], [], []
    for k, img in enumerate(images):
        g = np.float32(img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        if window is None or window.shape != g.shape[::-1]:
            window = cv2.createHanningWindow(g.shape[::-1], cv2.CV_32F)
        if prev is not None:
            (dx, dy), resp = cv2.phaseCorrelate(prev, g, window)
            t0s.append(times[k - 1])
            t1s.append(times[k])
            big = np.hypot(dx, dy) > 0.25 * min(g.shape)  # beyond what phase correlation measures reliably
            shifts.append((dx, dy) if resp >= 0.05 and not big else (np.nan, np.nan))
        prev = g
    t0, t1, s = np.array(t0s), np.array(t1s), np.array(shifts, float).reshape(-1, 2)
    gap = (t1 - t0) > MAX_PAIR_GAP_S
    s[gap] = np.nan
    return t0, t1, s


def interp_pos(track: FlightTrack, t: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, track.t_pos, track.pos_ned[:, i]) for i in range(3)], axis=1)


def interp_quat(track: FlightTrack, t: np.ndarray) -> np.ndarray:
    """Normalised linear interpolation of the (sign-continuous) quaternions."""
    q = np.stack([np.interp(t, track.t_att, track.quat[:, i]) for i in range(4)], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)


def _rotate_inv(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors ``v`` (N, 3) in the NED frame -> body frame of attitude ``q`` (body -> NED)."""
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    vq = np.c_[np.zeros(len(v)), v]
    return _qmul(_qmul(qc, vq), q)[:, 1:]


def _log_motion(track: FlightTrack, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """(N, 6): body-frame displacement (m; velocity at mid-interval times duration, since a
    position estimate may jump when a range sensor resets it) and rotation vector (rad, body axes)."""
    tm = 0.5 * (t0 + t1)
    v = np.stack([np.interp(tm, track.t_pos, track.vel_ned[:, i]) for i in range(3)], axis=1)
    q0, q1, qm = interp_quat(track, t0), interp_quat(track, t1), interp_quat(track, tm)
    disp = _rotate_inv(qm, v) * (t1 - t0)[:, None]
    dq = _qmul(q0 * np.array([1.0, -1.0, -1.0, -1.0]), q1)  # body rotation from t0 to t1, in body axes
    dq *= np.sign(dq[:, :1] + 1e-12)
    rot = 2.0 * dq[:, 1:]  # small-angle rotation vector
    return np.c_[disp, rot]


def _score(track: FlightTrack, t0: np.ndarray, t1: np.ndarray, s: np.ndarray, lag: float, min_pairs: int,
           fixed: np.ndarray | None = None) -> float:
    """Multiple correlation of the image shifts with the log's motion at offset ``lag``, over the
    pairs inside the log (or the ``fixed`` subset, so that scores of nearby lags compare the same pairs)."""
    a, b = t0 - lag, t1 - lag
    ok = (a >= track.start_s) & (b <= track.end_s) if fixed is None else fixed
    if ok.sum() < min_pairs:
        return np.nan
    y = s[ok]
    X = np.c_[np.ones(int(ok.sum())), _log_motion(track, a[ok], b[ok])]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    # one trimmed refit: pairs the fit misses by more than 4 robust sigmas (a frame that failed to
    # register, a flash) would otherwise swing the score as they enter or leave the log's span
    r = np.linalg.norm(y - X @ coef, axis=1)
    sigma = 1.4826 * np.median(r) + 1e-9
    keep = r <= 4.0 * sigma
    if keep.sum() >= min_pairs and not keep.all():
        X, y = X[keep], y[keep]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    sse = float(((y - X @ coef) ** 2).sum())
    sst = float(((y - y.mean(axis=0)) ** 2).sum())
    if sst < 1e-12:
        return 0.0
    return float(np.sqrt(max(0.0, 1.0 - sse / sst)))


def find_offset(track: FlightTrack, t0_cam: np.ndarray, t1_cam: np.ndarray, shift: np.ndarray, *, search: tuple[float, float],
                coarse_step_s: float = 0.05, fine_step_s: float = 0.002) -> Alignment:
    """Best camera-minus-log offset within ``search`` (log times = camera times - offset; camera
    times already on the log's clock base, e.g. UTC minus the log's UTC offset)."""
    ok = np.all(np.isfinite(shift), axis=1)
    t0, t1, s = t0_cam[ok], t1_cam[ok], shift[ok]
    min_pairs = max(5, int(0.5 * len(s)))
    lo, hi = search
    lags = np.arange(lo, hi + coarse_step_s / 2, coarse_step_s)
    sc = np.array([_score(track, t0, t1, s, L, min_pairs) for L in lags])
    if len(s) < 5 or not np.any(np.isfinite(sc)):
        return Alignment(0.0, METHOD, 0.0, None, None, int(len(s)), search)
    i = int(np.nanargmax(sc))
    best = lags[i]
    for _ in range(20):  # climb until the best fine lag is inside its window
        fine = np.arange(best - 2 * coarse_step_s, best + 2 * coarse_step_s + fine_step_s / 2, fine_step_s)
        fixed = (t0 - fine[-1] >= track.start_s) & (t1 - fine[0] <= track.end_s)  # inside the log for every fine lag
        fs = np.array([_score(track, t0, t1, s, L, min_pairs, fixed) for L in fine])
        if not np.any(np.isfinite(fs)):
            break
        j = int(np.nanargmax(fs))
        if 2 <= j <= len(fine) - 3 or not (search[0] < fine[j] < search[1]):
            break
        best = fine[j]
    if not np.any(np.isfinite(fs)):
        fine, fs = lags, sc
    j = int(np.nanargmax(fs))
    peak_lag, peak = fine[j], fs[j]
    if 0 < j < len(fine) - 1 and np.all(np.isfinite(fs[j - 1:j + 2])):
        y0, y1, y2 = fs[j - 1], fs[j], fs[j + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            peak_lag = fine[j] + 0.5 * (y0 - y2) / den * fine_step_s
    z = np.nan_to_num(sc, nan=-1.0)
    local_max = np.r_[False, (z[1:-1] > z[:-2]) & (z[1:-1] >= z[2:]), False]
    others = local_max & (np.abs(lags - peak_lag) > 0.5)
    second = float(z[others].max()) if np.any(others) else 0.0
    r2, r2_second = max(0.0, float(peak)) ** 2, max(0.0, second) ** 2
    # unexplained variance at the peak against at the best rival: correlations near 1 compress
    # differences that the residuals show plainly (0.99 vs 0.87 leaves 12x less unexplained)
    distinct = max(0.0, 1.0 - (1.0 - r2) / max(1.0 - r2_second, 1e-12)) if r2_second < 1.0 else 0.0
    conf = r2 * distinct
    return Alignment(float(peak_lag), METHOD, conf, float(peak), second, int(len(s)), search)
