"""A DEM's evidence as one record (evaluation/evidence.py), and its CSV tables."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from evaluation.evidence import DEMEvidence, dem_evidence, write_evidence_csvs
from evaluation.spectrum import fractional_brownian_surface
from terrain.core.tile import DEMTile


def test_one_record_with_a_fit_per_spectrum_and_tables_that_agree(tmp_path):
    rough = fractional_brownian_surface(128, 0.8, rms=3.0, seed=2)
    tiny = DEMTile.from_array(np.arange(16.0).reshape(4, 4))  # too small for a spectrum
    ev = dem_evidence([("rough", rough), ("tiny", tiny)])
    assert isinstance(ev, DEMEvidence)
    with pytest.raises(AttributeError):
        ev.spectra = ()  # frozen
    assert [d.label for d in ev.distributions] == ["rough", "tiny"]
    assert len(ev.fits) == len(ev.spectra) >= 1
    assert [s.label for s in ev.spectra] == ["rough"]
    # an fBm surface of Hurst exponent 0.8: the fit finds it (a property, not a default)
    assert ev.fits[0].hurst == pytest.approx(0.8, abs=0.15)
    files = write_evidence_csvs(ev, tmp_path)
    assert [f.name for f in files] == ["slope_distributions.csv", "slope_summary.csv",
                                       "spectra.csv"]
    with open(files[1], newline="") as fh:
        rows = {r["label"]: r for r in csv.DictReader(fh)}
    assert float(rows["rough"]["hurst"]) == pytest.approx(ev.fits[0].hurst, rel=1e-5)
    assert rows["tiny"]["hurst"] == ""
    # the summary holds the distribution's own quantiles
    assert float(rows["tiny"]["p50_deg"]) == pytest.approx(
        ev.distributions[1].quantiles["p50"], rel=1e-5)
