"""Seismic motions: synthetic spectrum-compatible accelerograms and record readers.

A motion is the vector of free-field ground acceleration a_g(t) = (a_x, a_y, a_z), m/s²,
sampled at a constant step (vertically incident waves, no kinematic interaction); the routes
apply it through the influence vectors of the three translations. ``Motion.components`` says
which components carry a motion: one (``[motion] direction``) or any non-empty subset of x, y,
z at once (``[motion] components``: a record file per component, or independent synthetic
components).

Synthetic motions (deterministic for a given seed): a Gaussian white noise under a
Jennings-type envelope, its Fourier amplitudes corrected iteratively until its 5 %-damped
response spectrum matches the target design spectrum, then baseline-corrected (linear trend
final velocity and displacement brought to zero) and scaled to the requested PGA (the
record is "normalised to 0.25 g" as in the paper). The spectral SHAPE follows the target;
its LEVEL is set by the PGA: for a 10 s record a Gaussian-noise motion whose spectrum matches
RG 1.60 has a PGA ~1.4 times the spectrum's ZPA, so after normalisation its 5 % spectrum
lies at ~0.7 (0.55-1.05) of the RG 1.60 spectrum anchored at the same PGA.

RG 1.60 horizontal design spectrum, 5 % damping (US NRC Regulatory Guide 1.60, Table I),
for a PGA of 1 g: control points A (33 Hz) Sa = 1.0 g, B (9 Hz) 2.61 g, C (2.5 Hz) 3.13 g,
D (0.25 Hz) Sd = 2.05 × 36 in; log-log linear between points, constant displacement below D.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from structure import G_ACC as G  # m/s^2 per g

from orchestrator.spectra import response_spectrum
from uplift_common.errors import UserInputError
from uplift_common.ranges import PLAUSIBLE, check_plausible

_IN = 0.0254
#: the choices of the [motion] keys (and of the readers' arguments)
SPECTRA = ("RG1.60",)
DIRECTIONS = ("x", "y", "z")
#: default peak of the synthetic vertical component over the horizontals' pga_g (the usual 2/3)
VERTICAL_RATIO = 2.0 / 3.0
FORMATS = ("two-column", "peer-at2")
UNITS = ("g", "m/s2")


class MotionError(UserInputError):
    """An invalid motion input; the message names the input and how to fix it."""


@dataclass(frozen=True, eq=False)
class Motion:
    """Ground acceleration, shape (nt, 3), m/s², columns x, y, z, step dt (s).

    components : the axes that carry a motion, in x, y, z order (default: the columns that are
    not identically zero)."""

    dt: float
    acc: np.ndarray
    label: str = "motion"
    components: tuple[str, ...] = ()

    def __post_init__(self):
        axes = self.components or [a for a, col in zip(DIRECTIONS, np.asarray(self.acc).T) if np.any(col)]
        unknown = set(axes) - set(DIRECTIONS)
        if unknown:
            raise MotionError(f"Motion.components: unknown component {sorted(unknown)[0]!r}; use \"x\", \"y\", \"z\"")
        object.__setattr__(self, "components", tuple(a for a in DIRECTIONS if a in axes))

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.acc.shape[0]) * self.dt

    @property
    def duration(self) -> float:
        return (self.acc.shape[0] - 1) * self.dt

    @property
    def pga(self) -> np.ndarray:
        """Peak ground acceleration per component, m/s²."""
        return np.abs(self.acc).max(axis=0)

    def resampled(self, dt: float) -> Motion:
        """Linear interpolation onto a new step (the input is piecewise linear); the motion
        itself when its step is already dt (to 1e-12 s)."""
        if abs(dt - self.dt) < 1e-12:
            return self
        t_new = dt * np.arange(int(np.floor(self.duration / dt + 1e-9)) + 1)
        acc = np.column_stack([np.interp(t_new, self.time, self.acc[:, k]) for k in range(3)])
        return Motion(dt, acc, self.label, self.components)


def rg160_psa(freq_hz, pga: float = 1.0):
    """RG 1.60 horizontal 5 %-damped pseudo-acceleration, same unit as pga (see module doc)."""
    f = np.asarray(freq_hz, float)
    sd_d = 2.05 * 36 * _IN * pga / G          # Sd at D per unit of pga expressed in g·(m/s²)/G
    psa_d = (2 * np.pi * 0.25) ** 2 * sd_d
    pts_f = np.array([0.25, 2.5, 9.0, 33.0])
    pts_a = np.array([psa_d, 3.13 * pga, 2.61 * pga, 1.0 * pga])
    out = np.exp(np.interp(np.log(f), np.log(pts_f), np.log(pts_a)))
    out = np.where(f < 0.25, psa_d * (f / 0.25) ** 2, out)
    return np.where(f > 33.0, pga, out)


def _envelope(t, duration):
    """Jennings envelope: quadratic rise (first 15 %), strong phase, exponential decay (last 40 %)."""
    t1, t2 = 0.15 * duration, 0.6 * duration
    env = np.ones_like(t)
    env[t < t1] = (t[t < t1] / t1) ** 2
    late = t > t2
    env[late] = np.exp(-3.0 * (t[late] - t2) / (duration - t2))
    return env


def _baseline(acc, dt, env):
    """Baseline correction: subtract (c0 + c1 t) env(t), with c0, c1 chosen so that the final
    ground velocity and displacement are zero; the quiet start stays quiet."""
    t = np.arange(acc.size) * dt
    T = t[-1]

    def final_vd(a):  # trapezoidal velocity and displacement at the end
        v = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)])
        return np.array([v[-1], np.trapezoid(v, dx=dt) if hasattr(np, "trapezoid") else np.trapz(v, dx=dt)])

    basis = np.column_stack([final_vd(env), final_vd(t / T * env)])
    c = np.linalg.solve(basis, final_vd(acc))
    return acc - (c[0] + c[1] * t / T) * env


#: step at which synthetic records are generated, whatever the analysis step: the record is a
#: property of the scene, not of dt (a time-step study compares one motion, linearly resampled)
SYNTHETIC_DT = 0.005


def synthetic_motion(pga_g: float = 0.25, duration_s: float = 10.0, dt: float = 0.005, seed: int = 1,
                     spectrum: str = "RG1.60", iterations: int = 8, direction="x") -> Motion:
    """Spectrum-compatible synthetic accelerogram (deterministic for a seed).

    The record is generated at SYNTHETIC_DT and resampled linearly to ``dt`` (it is piecewise
    linear, so a finer dt samples the same motion exactly; a coarser dt keeps its values at the
    common instants and may miss the peak between them). Returns a Motion whose ``direction``
    component ("x", "y" or "z") carries the record (its generator seeded with ``seed``).
    """
    axis = _axis(direction)
    _check_synthetic(pga_g, duration_s, dt, spectrum)
    acc = _synthetic(pga_g, duration_s, SYNTHETIC_DT, seed, spectrum, iterations)
    out = np.zeros((acc.size, 3))
    out[:, axis] = acc
    return Motion(SYNTHETIC_DT, out, f"synthetic {spectrum} {pga_g:g} g seed {seed}", (direction,)).resampled(dt)


def synthetic_components(pga_g: float = 0.25, duration_s: float = 10.0, dt: float = 0.005, seed: int = 1,
                         spectrum: str = "RG1.60", iterations: int = 8, components=DIRECTIONS,
                         vertical_ratio: float = VERTICAL_RATIO) -> Motion:
    """Statistically independent spectrum-compatible components at once (deterministic for a seed).

    components : a non-empty subset of "x", "y", "z". Each is generated like
    ``synthetic_motion`` (same spectrum shape, envelope and baseline correction) from its own
    generator: the child k of ``numpy.random.SeedSequence(seed)`` for axis k (x 0, y 1, z 2), so
    a component does not depend on which others are asked for. The horizontals peak at pga_g,
    the vertical at vertical_ratio x pga_g (g).
    """
    axes = check_components(components)
    _check_synthetic(pga_g, duration_s, dt, spectrum)
    if not (isinstance(vertical_ratio, (int, float)) and 0 < vertical_ratio <= 2):
        raise MotionError(f"motion.vertical_ratio = {vertical_ratio!r}: the vertical peak over pga_g must lie in "
                          "(0, 2], e.g. 2/3")
    children = np.random.SeedSequence(seed).spawn(len(DIRECTIONS))
    out = None
    for a in axes:
        k = DIRECTIONS.index(a)
        peak = pga_g * (vertical_ratio if a == "z" else 1.0)
        acc = _synthetic(peak, duration_s, SYNTHETIC_DT, children[k], spectrum, iterations)
        out = np.zeros((acc.size, 3)) if out is None else out
        out[:, k] = acc
    ratio = f", z at {vertical_ratio:.3g} of it" if "z" in axes else ""
    label = f"synthetic {spectrum} {pga_g:g} g{ratio}, seed {seed}"
    return Motion(SYNTHETIC_DT, out, label, axes).resampled(dt)


def _check_synthetic(pga_g, duration_s, dt, spectrum):
    if spectrum not in SPECTRA:
        raise MotionError(f"motion.spectrum = {spectrum!r}: only \"RG1.60\" is available")
    if not (pga_g > 0) or not (duration_s > 0) or not (dt > 0) or duration_s < 20 * max(dt, SYNTHETIC_DT):
        raise MotionError("motion: pga_g, duration_s and dt must be > 0, duration_s >= 20 dt")


def _synthetic(pga_g, duration_s, dt, seed, spectrum, iterations) -> np.ndarray:
    """One component (n,), m/s², peak pga_g (g); seed: an integer or a numpy SeedSequence."""
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    env = _envelope(t, duration_s)
    rng = np.random.default_rng(seed)
    acc = rng.standard_normal(n) * env
    freqs = np.fft.rfftfreq(n, dt)
    f_ctrl = np.geomspace(0.2, min(33.0, 0.4 / dt), 60)
    target = rg160_psa(f_ctrl, pga_g * G)
    for _ in range(iterations):
        spec = response_spectrum(acc, dt, 1.0 / f_ctrl, 0.05)
        ratio = target / spec.psa
        corr = np.interp(freqs, f_ctrl, ratio, left=ratio[0], right=ratio[-1])
        acc = np.fft.irfft(np.fft.rfft(acc) * corr, n) * env
    acc = _baseline(acc, dt, env)
    return acc * (pga_g * G / np.abs(acc).max())


def _axis(direction) -> int:
    if direction not in DIRECTIONS:
        raise MotionError(f"motion.direction = {direction!r}: use \"x\", \"y\" or \"z\"")
    return DIRECTIONS.index(direction)


def check_components(components, where: str = "motion.components") -> tuple:
    """The axes of ``components`` (a non-empty collection of "x", "y", "z", each once) in x, y, z order."""
    if isinstance(components, str) or not isinstance(components, (list, tuple, dict)) or not components:
        raise MotionError(f"{where} = {components!r} must name a non-empty subset of \"x\", \"y\", \"z\", "
                          'e.g. ["x", "y", "z"]')
    for a in components:
        if a not in DIRECTIONS:
            raise MotionError(f"{where}: unknown component {a!r}; components are \"x\", \"y\" (horizontal) "
                              'and "z" (vertical, up)')
        if list(components).count(a) > 1:
            raise MotionError(f"{where} lists {a!r} twice")
    return tuple(a for a in DIRECTIONS if a in components)


def make_motion(config, dt: float) -> Motion:
    """The motion of a scene's [motion] (an ``orchestrator.scene.MotionConfig``) at step dt (s).

    Synthetic: ``synthetic_motion`` on ``direction``, or ``synthetic_components`` (generated at
    SYNTHETIC_DT, resampled linearly to dt). Record: the file(s) read (the copy read when the
    scene was loaded, ``config.record``, if any), resampled linearly to dt when its step differs.
    """
    if config.kind == "synthetic":
        common = dict(pga_g=config.pga_g, duration_s=config.duration_s, dt=dt, seed=config.seed,
                      spectrum=config.spectrum)
        if config.direction is not None:
            return synthetic_motion(**common, direction=config.direction)
        return synthetic_components(**common, components=config.components, vertical_ratio=config.vertical_ratio)
    rec = getattr(config, "record", None)
    if rec is None:
        rec = read_components(config.files, config.format, config.units, config.scale)
    return rec.resampled(dt)


def read_record(path, fmt: str = "two-column", units: str = "g", scale: float = 1.0, direction="x", *,
                where: str = "motion.file") -> Motion:
    """Read an accelerogram: PEER NGA ``.AT2`` or two-column text (time, acceleration).

    units: "g" or "m/s2"; scale multiplies the record; the record goes on ``direction``.
    The file must be UTF-8 (or ASCII) text; a malformed file is a MotionError naming the file
    and the line at fault (``where``: the scene key that gave the file).
    """
    path = Path(path)
    if not path.is_file():
        raise MotionError(f"{where} = {str(path)!r}: no such file (paths are relative to the scene file)")
    if units not in UNITS:
        raise MotionError(f"motion.units = {units!r}: use \"g\" or \"m/s2\"")
    if fmt not in FORMATS:
        raise MotionError(f"motion.format = {fmt!r}: use \"peer-at2\" or \"two-column\"")
    axis = _axis(direction)
    dt, acc = (_read_at2 if fmt == "peer-at2" else _read_two_column)(path, _lines(path))
    _plausible_samples(path, acc, units)
    acc = acc * scale * (G if units == "g" else 1.0)
    out = np.zeros((acc.size, 3))
    out[:, axis] = acc
    return Motion(dt, out, f"{path.name} x{scale:g}", (direction,))


def read_components(files, fmt: str = "two-column", units: str = "g", scale: float = 1.0) -> Motion:
    """Read one record per component at once: ``files`` {axis: path} or pairs (axis, path), axes
    a non-empty subset of "x", "y", "z"; format, units and scale as ``read_record``, for all.

    The components must share their time step (to 1e-6 relative) and their number of samples:
    otherwise a MotionError names every file with its step and length (no resampling, no
    zero padding: trim or resample the files to a common time base).
    """
    files = dict(files)
    axes = check_components(list(files))
    parts = {a: read_record(files[a], fmt, units, scale, a, where=f"motion.components.{a}") for a in axes}
    first = parts[axes[0]]
    steps = [m.dt for m in parts.values()]
    sizes = [m.acc.shape[0] for m in parts.values()]
    if max(steps) - min(steps) > 1e-6 * min(steps) or len(set(sizes)) > 1:
        listing = "; ".join(f"{a} = {Path(files[a]).name!r}: {m.acc.shape[0]} samples at dt = {m.dt:g} s"
                            for a, m in parts.items())
        what = "time steps" if max(steps) - min(steps) > 1e-6 * min(steps) else "lengths"
        raise MotionError(f"motion.components: the records differ in their {what} ({listing}); the components "
                          "of a motion share one time base: resample or trim the files to a common step and "
                          "length (they are not zero-padded)")
    acc = sum(m.acc for m in parts.values())
    label = ", ".join(f"{a}: {Path(files[a]).name}" for a in axes) + f" x{scale:g}"
    return Motion(first.dt, acc, label, axes)


def _plausible_samples(path, acc, units: str) -> None:
    """Refuse (MotionError) a record with a sample beyond the plausible range of its units
    (uplift_common.ranges: 50 g, 500 m/s2), naming the file and the sample, before any
    arithmetic on it (a sample of 1e308 would overflow the scaling)."""
    quantity = "sample_g" if units == "g" else "sample_ms2"
    bad = np.flatnonzero(np.abs(acc) > PLAUSIBLE[quantity].hi)
    if bad.size:
        check_plausible(f"{path}: sample {bad[0] + 1} of {acc.size}", float(acc[bad[0]]), quantity, MotionError)


def _lines(path: Path) -> list:
    """The file's text lines (UTF-8, a byte-order mark ignored)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MotionError(f"{path}: cannot read the record: {exc.strerror}") from None
    try:
        return raw.decode("utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise MotionError(f"{path}, line {line}: byte {raw[exc.start]:#04x} is not UTF-8 text; "
                          "save the record as plain text") from None


def _numbers(path, lineno: int, tokens) -> list:
    """Finite floats of one line's tokens, or a MotionError naming the line."""
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise MotionError(f"{path}, line {lineno}: {' '.join(tokens)[:60]!r} is not a list of numbers") from None
    if not all(map(math.isfinite, values)):
        raise MotionError(f"{path}, line {lineno}: {' '.join(tokens)[:60]!r}: values must be finite")
    return values


def _read_two_column(path, lines):
    """Time (s) and acceleration per line, whitespace separated, constant step; '#' starts a comment."""
    rows, where = [], []
    for k, line in enumerate(lines, start=1):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if len(tokens) != 2:
            raise MotionError(f"{path}, line {k}: expected two columns (time, acceleration), "
                              f"got {len(tokens)} values")
        rows.append(_numbers(path, k, tokens))
        where.append(k)
    if len(rows) < 2:
        raise MotionError(f"{path}: expected at least two lines of two columns (time, acceleration), "
                          f"got {len(rows)}")
    data = np.array(rows)
    far = np.flatnonzero(np.abs(data[:, 0]) > PLAUSIBLE["record_time"].hi)
    if far.size:          # before the differences (which would overflow)
        check_plausible(f"{path}, line {where[far[0]]}: time", float(data[far[0], 0]), "record_time", MotionError)
    steps = np.diff(data[:, 0])
    if np.any(steps <= 0) or np.ptp(steps) > 1e-6 * steps.mean():
        bad = int(np.argmax(steps <= 0)) if np.any(steps <= 0) else int(np.argmax(np.abs(steps - steps[0])))
        raise MotionError(f"{path}, line {where[bad + 1]}: time step {steps[bad]:g} s against {steps[0]:g} s "
                          "at the start: the time column must increase with a constant step")
    return float(steps.mean()), data[:, 1]


def _read_at2(path, lines):
    """PEER NGA AT2: four header lines (the fourth gives NPTS and DT), then NPTS values in g."""
    if len(lines) < 5:
        raise MotionError(f"{path}: too short for a PEER AT2 file (4 header lines then data)")
    header = lines[3].replace(",", " ").upper()
    fields = header.split()
    npts_s, dt_s = (re.search(rf"(?<![A-Z]){key}\s*=\s*(\S+)", header) for key in ("NPTS", "DT"))
    try:
        npts = float(npts_s.group(1) if npts_s else fields[0])
        dt = float(dt_s.group(1) if dt_s else fields[1])
    except (ValueError, IndexError):
        raise MotionError(f"{path}, line 4: cannot read NPTS and DT in the PEER AT2 header "
                          f"{lines[3].strip()[:60]!r} (e.g. 'NPTS=  4000, DT=   .0050 SEC')") from None
    if not (math.isfinite(npts) and npts >= 2 and npts == int(npts)):
        raise MotionError(f"{path}, line 4: NPTS = {npts:g} must be a whole number of samples >= 2")
    if not (math.isfinite(dt) and dt > 0):
        raise MotionError(f"{path}, line 4: DT = {dt:g} must be a time step > 0 s")
    npts = int(npts)
    values = [v for k, line in enumerate(lines[4:], start=5) for v in _numbers(path, k, line.split())]
    if len(values) < npts:
        raise MotionError(f"{path}, line 4: header says NPTS = {npts} but {len(values)} values follow "
                          f"(lines 5-{len(lines)})")
    return dt, np.array(values[:npts])
