"""calibrate's uncertainty covers the true K on photos no tuning saw (issue 42).

The photos are the 12 even-numbered Kodak PhotoCD crops in tests/data/kodak
(kodim02 … kodim24, centre 256 × 256). They were chosen by number and vendored
before the patch method's systematic error was changed, and nothing was tuned on
them: the tuning used the six photos of tests/data/srgb and srgb16 (centre and
corner crops; see test_calibrate_coverage) and, as a check before this one, the
odd-numbered Kodak photos (not vendored). This test was run once, after the
method was settled; its figures below are that run's.

As in the issue: each photo upsampled 4× (1024² at camera resolution),
unprocessed with the Sony A7S II profile's physics noise at ISO 800 and 3200
with seeds 1 and 2, and fitted with the patch method on its own (48 fits) and
in three sets of four photos (12 fits). Measured: 51 of 60 fits accepted (7
single-photo fits and 2 sets refused, all for a negative read variance or bins
off the line), and all 51 within 2σ (50 within 1σ: the bound is conservative
here, ±5.5 % median against a median error of 1.7 %). The 6th-order check alone
also covered all 51 at 2σ (39 at 1σ): these crops are less textured than the
issue's photos; test_calibrate_coverage's textured crops are where it failed.
"""

import numpy as np
import pytest

from rawsim.api import unprocess
from rawsim.cameras.calibrate import calibrate_iso, frame_stats
from tests.test_calibrate_coverage import SENSOR, _camera_photo, _raw

#: Coverage over many fits of unprocessed photos: an acceptance test, in the slow tier.
pytestmark = pytest.mark.slow

PHOTOS = tuple(f"kodak/kodim{i:02d}_crop.png" for i in range(2, 25, 2))
SETS = (PHOTOS[0:4], PHOTOS[4:8], PHOTOS[8:12])
ISOS = (800, 3200)
SEEDS = (1, 2)


@pytest.fixture(scope="module")
def heldout_fits() -> list[tuple[str, float, float, object]]:
    """(photos, ISO, true K, fit): 48 single-photo fits, then 12 fits of four photos."""
    stats, truth = {}, {}
    for name in PHOTOS:
        image = _camera_photo(name)
        for iso in ISOS:
            for seed in SEEDS:
                noisy, _, meta = unprocess(image, SENSOR, [seed], iso=iso, noise="physics")
                stats[name, iso, seed] = frame_stats(_raw(noisy, iso), "patches")
                truth[iso] = meta[0]["noise"]["gain_dn_per_electron"]
    fits = [
        (name, iso, truth[iso], calibrate_iso(iso, [stats[name, iso, seed]], [], "patches"))
        for name in PHOTOS
        for iso in ISOS
        for seed in SEEDS
    ]
    for photos in SETS:
        for iso in ISOS:
            for seed in SEEDS:
                together = [stats[name, iso, seed] for name in photos]
                fit = calibrate_iso(iso, together, [], "patches")
                fits.append(("+".join(photos), iso, truth[iso], fit))
    return fits


def test_heldout_fits_cover_the_true_gain_at_two_sigma(heldout_fits):
    assert len(heldout_fits) == 60
    accepted = [f for f in heldout_fits if not f[3].problems]
    # Most fits are accepted, so coverage is not bought by refusing the hard ones.
    assert len(accepted) >= 0.7 * len(heldout_fits), [f[3].problems for f in heldout_fits]
    assert len([f for f in accepted if "+" in f[0]]) >= 9  # sets of four, as in the issue
    covered = [abs(fit.K - truth) <= 2 * fit.errors["K"] for _, _, truth, fit in accepted]
    report = [
        f"{name} ISO {iso}: K {fit.K:.4g} ± {fit.errors['K']:.2g} (truth {truth:.4g})"
        for (name, iso, truth, fit), ok in zip(accepted, covered, strict=True)
        if not ok
    ]
    assert len(covered) >= 30 and np.mean(covered) >= 0.9, report
