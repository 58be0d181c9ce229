"""An organ's light at one step, as the growth rules read it: :class:`OrganLight`, a step's :class:`StepResult`, and
how both are made from a run's tallies (:func:`organ_lights`) and written (:data:`ORGAN_COLUMNS`, :func:`organ_rows`).

Units: ``ppfd`` µmol m⁻² s⁻¹ incident (either side, over the organ's one-sided area), ``absorbed`` µmol s⁻¹,
``par`` µmol m⁻² s⁻¹ (the bands tiling 400-700 nm), ``rfr`` 655-665 / 725-735 nm without a ratio's bias
(:mod:`lpy_light.chamber.ratios`); each with its standard error.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..chamber import units
from ..chamber.ratios import MAX_DENOMINATOR_CV

log = logging.getLogger("lpy_light")

NOT_REACHED = "not reached"    # an OrganLight's role when no sample of the step reached the organ


@dataclass
class OrganLight:
    """The light of one organ at one step (arrays are per band, ``bands`` labels).

    Readable as attributes (``light.par``) or items (``light['par']``) from L-Py rules.  Each number has its
    standard error beside it (``par_std``, ...); a number the step could not define is NaN.

    Attributes
    ----------
    key : object
        The organ's key: its module's index in the L-string (L-Py), or the mapping's key (meshes).
    module : str
        The organ's module name (``"Leaf"``).
    bands : list of str
        The scene's band labels (``"655-665"``), nm.
    area_m2 : float
        The organ's one-sided area, m².
    photons, photons_std : (B,) ndarray
        Expected photon hits for the step's photons, per band (a count).
    ppfd, ppfd_std : (B,) ndarray
        Incident photon flux density, per band: photons hitting the organ (either side) per second over its
        one-sided area, µmol m⁻² s⁻¹.
    absorbed, absorbed_std : (B,) ndarray
        Absorbed by the organ, per band, µmol s⁻¹.
    par, par_std : float
        PAR incident (the bands tiling 400-700 nm), µmol m⁻² s⁻¹; NaN when the bands do not tile it.
    rfr, rfr_std : float
        R:FR, ppfd 655-665 / ppfd 725-735 nm (dimensionless), without the first-order bias of a ratio of two
        estimates; NaN where the far red is too uncertain for that, or a band is missing.
    absorbed_par, absorbed_par_std : float
        Absorbed in the bands tiling 400-700 nm, µmol s⁻¹.
    role : str
        ``"target"``; ``"shading only"``: the organ blocks light, its own is not estimated (numbers NaN);
        ``"not reached"``: no sample of the step reached it (numbers NaN, the rules get None).
    """

    key: object
    module: str
    bands: list
    area_m2: float
    photons: np.ndarray          # (B,) expected photon hits for the run's N photons
    photons_std: np.ndarray
    ppfd: np.ndarray             # (B,) µmol m⁻² s⁻¹ incident
    ppfd_std: np.ndarray
    absorbed: np.ndarray         # (B,) µmol s⁻¹
    absorbed_std: np.ndarray
    par: float = float("nan")
    par_std: float = float("nan")
    rfr: float = float("nan")
    rfr_std: float = float("nan")
    absorbed_par: float = float("nan")     # µmol s⁻¹ absorbed in the bands tiling 400-700 nm
    absorbed_par_std: float = float("nan")
    role: str = "target"         # "target"; "shading only": the organ blocks light, its own is not estimated;
    #                              "not reached": no sample of the step reached it (numbers NaN, the rules get None)

    def __getitem__(self, name):
        return getattr(self, name)

    def band(self, label: str) -> float:
        """ppfd of the band labelled ``label`` (e.g. '655-665')."""
        return float(self.ppfd[self.bands.index(label)])


@dataclass
class StepResult:
    """All organs of one step, with the run's figures.

    Attributes
    ----------
    step : int
        The step's number, from 0.
    organs : dict
        ``{key: OrganLight}``, every organ of the step (targets, "shading only", "not reached").
    photons : int
        Photons the step's numbers are for (a count; for ``reuse`` and ``field``, the store's or field's photons).
    seconds : float
        Wall-clock seconds of the step's run (s), the kernel's first compile included (the L-Py shapes'
        conversion before it: ``extra["convert_seconds"]``).
    triangles : int
        The organs' triangles (a count).
    tessellated : int
        Organs converted this step (tessellation cache misses; a count).
    reused : int
        Organs taken from the tessellation cache (a count).
    extra : dict
        What else the step reports: ``precision`` and ``precision_reached``, ``outside_chamber`` (keys of organs
        outside the chamber), ``store`` (the stored estimators' store or field), ``field_check`` (the self-check
        of a field traced at this step) and ``lit_by`` (``field``, or ``nee`` where the field failed it),
        ``verify`` (a verified step's comparison with ``nee``, kind by kind), ``sigma_over_goal``,
        ``compile_seconds``, ``convert_seconds`` and ``verify_seconds`` (s).
    comparison : list
        A verified step's rows of ``verify.csv`` (:data:`lpy_light.plant.verify.VERIFY_COLUMNS`), else empty.
    """

    step: int
    organs: dict                 # key -> OrganLight
    photons: int
    seconds: float
    triangles: int
    tessellated: int             # organs converted this step (cache misses)
    reused: int                  # organs taken from the cache
    extra: dict = field(default_factory=dict)
    comparison: list = field(default_factory=list)     # rows of verify.csv (LightModel(verify=N))


def organ_lights(kscene, result, organs, flux, flux_std, chamber, read=None) -> dict:
    """Per organ: photons, ppfd, absorbed, PAR, R:FR, each with σ; ``{key: OrganLight}``.

    ``read`` (n,) bool: the organs whose light is estimated (the targets); the others are
    "shading only": they block and scatter light, and their numbers are NaN (empty cells), not
    the few photons that happened to land on them."""
    R0, N = kscene.n_chamber_receivers, result.photons
    inc, inc_std = result.receivers_incident()
    ab, ab_std = result.receivers_absorbed()
    m2 = chamber.metres_per_unit ** 2
    labels = chamber.band_labels
    out = {}

    def scaled(x, sx, per):
        value = x * flux / N / per
        with np.errstate(divide="ignore", invalid="ignore"):
            rel2 = np.where(x > 0, (sx / np.where(x > 0, x, 1)) ** 2, 0) + (flux_std / flux) ** 2
        std = np.where(x > 0, np.abs(value) * np.sqrt(rel2), sx * flux / N / per)
        return value, std

    rows = R0 + np.arange(len(organs))                 # rows of receivers_incident()
    cov = result.covariance(result.n_sensors + rows) if len(organs) else np.zeros((0, len(flux), len(flux)))
    areas = np.array([o.area * m2 for o in organs])
    scale = flux[None, :] / N / np.maximum(areas, 1e-300)[:, None]
    scale_std = flux_std[None, :] / N / np.maximum(areas, 1e-300)[:, None]
    par, par_std, rfr, rfr_std = units.par_and_rfr(inc[rows], cov, scale, scale_std, chamber.bands)
    if rfr is not None:
        _say_unreported_rfr(rfr, inc[rows, units.band_index(chamber.bands, units.FAR_RED)], read)
    absorbed_rows = result.n_sensors + kscene.n_receivers + rows
    cov_ab = result.covariance(absorbed_rows) if len(organs) else cov
    ab_par, ab_par_std, _, _ = units.par_and_rfr(ab[rows], cov_ab, np.broadcast_to(flux / N, scale.shape),
                                                 np.broadcast_to(flux_std / N, scale.shape), chamber.bands)
    for i, organ in enumerate(organs):
        r = R0 + i
        ppfd, ppfd_std = scaled(inc[r], inc_std[r], areas[i])
        absorbed, absorbed_std = scaled(ab[r], ab_std[r], 1.0)
        light = OrganLight(organ.key, organ.module, labels, areas[i], inc[r].copy(), inc_std[r].copy(),
                           ppfd, ppfd_std, absorbed, absorbed_std)
        if par is not None:
            light.par, light.par_std = float(par[i]), float(par_std[i])
        if rfr is not None:
            light.rfr, light.rfr_std = float(rfr[i]), float(rfr_std[i])
        if ab_par is not None:
            light.absorbed_par, light.absorbed_par_std = float(ab_par[i]), float(ab_par_std[i])
        if read is not None and not read[i]:
            light = shading_only(light)
        elif not (inc[r] > 0).any() and not (inc_std[r] > 0).any():
            light = not_reached(light)
            log.warning("organ %r (%s, %.3g m²): no sample of this step reached it, so its light is undefined: "
                        "None for the rules, empty cells in organs.csv (more photons, or a precision, reach it)",
                        organ.key, organ.module or "organ", areas[i])
        out[organ.key] = light
    return out


def _say_unreported_rfr(rfr, far_red, read):
    """Warn when target organs with far red get no R:FR (NaN): their far red's σ is too large for the ratio's
    bias correction to hold (:data:`lpy_light.chamber.ratios.MAX_DENOMINATOR_CV`)."""
    missing = ~np.isfinite(rfr) & (far_red > 0) & (True if read is None else np.asarray(read, bool))
    if missing.any():
        log.warning("R:FR not reported (NaN, an empty cell) for %d target organ(s): their far red's relative "
                    "standard error is above %g, where a ratio's bias cannot be corrected; trace more photons "
                    "or ask a precision on R:FR (precision={'rfr': 0.02})", int(missing.sum()),
                    MAX_DENOMINATOR_CV)


def shading_only(light: OrganLight) -> OrganLight:
    """The light of an organ that is not a target: every number undefined (NaN), ``role`` says why."""
    return _undefined(light, "shading only")


def not_reached(light: OrganLight) -> OrganLight:
    """The light of a target organ that no sample of the step reached (no photon, no next event): not 0 ± 0,
    which would claim a certainty the run does not have, but every number undefined (NaN: empty cells in
    ``organs.csv``); the rules get None (:func:`for_rules`)."""
    return _undefined(light, NOT_REACHED)


def _undefined(light, role):
    nan = np.full(len(light.bands), np.nan)
    return replace(light, photons=nan, photons_std=nan, ppfd=nan, ppfd_std=nan, absorbed=nan, absorbed_std=nan,
                   par=math.nan, par_std=math.nan, rfr=math.nan, rfr_std=math.nan, absorbed_par=math.nan,
                   absorbed_par_std=math.nan, role=role)


def for_rules(lights: dict) -> dict:
    """``{key: OrganLight or None}``: what the growth rules read -- None for an organ no sample reached, as
    before the organ's first step."""
    return {key: None if light.role == NOT_REACHED else light for key, light in lights.items()}


#: the columns of ``organs.csv``, one row per organ and band (``role``: "target", "shading only", "not reached")
ORGAN_COLUMNS = ("step", "organ", "module", "band", "ppfd", "ppfd_std", "absorbed", "absorbed_std", "photons",
                 "photons_std", "area_m2", "par", "par_std", "rfr", "rfr_std", "absorbed_par", "absorbed_par_std",
                 "role")


def organ_rows(step: StepResult) -> list:
    """Rows of ``organs.csv`` (:data:`ORGAN_COLUMNS`): one per organ and band."""
    rows = []
    for key, light in step.organs.items():
        for b, label in enumerate(light.bands):
            rows.append({"step": step.step, "organ": key, "module": light.module, "band": label,
                         "ppfd": light.ppfd[b], "ppfd_std": light.ppfd_std[b],
                         "absorbed": light.absorbed[b], "absorbed_std": light.absorbed_std[b],
                         "photons": light.photons[b], "photons_std": light.photons_std[b],
                         "area_m2": light.area_m2, "par": light.par, "par_std": light.par_std,
                         "rfr": light.rfr, "rfr_std": light.rfr_std, "absorbed_par": light.absorbed_par,
                         "absorbed_par_std": light.absorbed_par_std, "role": light.role})
    return rows
