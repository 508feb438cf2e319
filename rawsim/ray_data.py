"""Noisy/clean raw pairs for Ray Data: a callable class for ``Dataset.map_batches``.

A training job reads images with ``ray.data.read_images(..., include_paths=True)``
and maps them through :class:`RawPairs`, which unprocesses each row in memory,
seeded by its path relative to ``root``: row by row the same samples that
``rawsim unprocess ROOT -o OUT --seed SEED`` writes into OUT's DNGs, with no DNG
written::

    import ray
    from rawsim.ray_data import RawPairs

    images = ray.data.read_images("s3://bucket/photos", include_paths=True, mode="RGB")
    pairs = images.map_batches(
        RawPairs,
        fn_constructor_kwargs=dict(profile="sony_a7s2", root="s3://bucket/photos",
                                   iso_range=(100, 12800), randomize=True, seed=7),
        batch_size=16,
        compute=ray.data.ActorPoolStrategy(size=4),  # leave CPUs for read_images
    )
    for batch in pairs.iter_batches(batch_size=16): ...

Ray Data decodes with Pillow and does not apply EXIF orientation; the CLI decodes
with OpenImageIO and records the orientation as a DNG tag instead. Both give the
same samples for PNG (and for JPEG where the two libjpeg builds agree: they do for
the bundled photos).
"""

from __future__ import annotations

import json
from pathlib import PurePosixPath

import numpy as np

from rawsim.api import capture_metadata
from rawsim.cameras.profiles import SensorProfile, load_profile
from rawsim.errors import ParameterError
from rawsim.io.images import even_rgb
from rawsim.io.lensfun import LensParams
from rawsim.noise.seeds import derive_seed
from rawsim.pipelines.unprocess import Simulation, UnprocessOptions, simulate

#: Full-scale codes of integer images; float images are scene-linear.
_CODE_MAX = {np.dtype(np.uint8): 255, np.dtype(np.uint16): 65535}


def row_key(path: str, root: str) -> str:
    """The key of an image at ``path`` under ``root`` (the CLI's key: the relative path
    with ``/``). Ray Data writes paths without the URL scheme (``bucket/a.png``)."""
    bare = lambda p: str(p).split("://", 1)[-1].rstrip("/")  # noqa: E731
    try:
        return PurePosixPath(bare(path)).relative_to(bare(root)).as_posix()
    except ValueError:
        raise ParameterError(f"{path} is not under the root {root}") from None


class RawPairs:
    """``map_batches`` callable: rows {"image", "path"} → noisy/clean raw pairs.

    Output columns, one row per input row:

    * ``key``: the image's path relative to ``root``; ``file_seed``: its seed;
    * ``noisy``, ``clean``: uint16 (H', W') mosaics in DN, H' and W' the image's
      size cropped to even numbers (``clean`` only if ``clean``), in the profile's
      CFA (or ``cfa``) from the top-left pixel: Bayer, X-Trans or any periodic layout;
    * ``iso``: float; ``metadata``: JSON of what was drawn and used (seed, ISO, CFA,
      levels, colour and noise parameters), as in :func:`rawsim.api.unprocess`.

    Args:
        profile: a bundled profile's name, a profile JSON's path, or a profile.
        root: the folder (path or URL) the CLI would be given; keys are relative to it.
        seed: the run's seed, as ``--seed``.
        iso: one ISO for every row, as ``--iso`` (give this or ``iso_range``).
        iso_range: (MIN, MAX), as ``--iso-range``.
        randomize: as ``--randomize``.
        noise: as ``--noise``.
        tone: as ``--tone``.
        transfer: as ``--transfer``.
        exposure_ev: as ``--exposure``.
        vignetting: as ``--vignetting``.
        safe_white_balance: True for ``--wb-inverse safe``, False for ``exact`` (the
            default).
        sensor: ``rgb`` or ``mono``, as ``--sensor``.
        cfa: another CFA layout for the profile, as ``--cfa`` (e.g. ``"XTRANS"``);
            None keeps the profile's.
        clean: also return the noise-free mosaic.
        lens: as ``--lens`` (with its focal length and aperture): a
            :class:`~rawsim.io.lensfun.LensParams` or its record, or None.
    """

    def __init__(
        self,
        profile: str | SensorProfile,
        *,
        root: str,
        seed: int = 0,
        iso: float | None = None,
        iso_range: tuple[float, float] | None = None,
        randomize: bool = False,
        noise: str = "poisson-gaussian",
        tone: str = "none",
        transfer: str = "srgb",
        exposure_ev: float = 0.0,
        vignetting: float = 0.0,
        safe_white_balance: bool = False,
        sensor: str = "rgb",
        cfa: str | None = None,
        clean: bool = True,
        lens: LensParams | dict | None = None,
    ) -> None:
        prof = profile if isinstance(profile, SensorProfile) else load_profile(profile)
        if (iso is None) == (iso_range is None):
            raise ParameterError("give exactly one of iso or iso_range")
        self.options = UnprocessOptions(
            profile=prof,
            iso=iso,
            iso_range=tuple(iso_range) if iso_range else None,
            randomize=randomize,
            clean=clean,
            noise=noise,
            tone=tone,
            transfer=transfer,
            exposure_ev=exposure_ev,
            vignetting=vignetting,
            safe_white_balance=safe_white_balance,
            seed=seed,
            sensor=sensor,
            lens=lens,
        ).with_cfa(cfa)
        self.options.check_isos()
        self.sensor = self.options.make_sensor()
        self.root, self.seed = root, seed

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, list]:
        if "path" not in batch:
            raise ParameterError("rows need a 'path' column: read_images(..., include_paths=True)")
        out: dict[str, list] = {"key": [], "file_seed": [], "noisy": [], "iso": [], "metadata": []}
        if self.options.clean:
            out["clean"] = []
        for image, path in zip(batch["image"], batch["path"], strict=True):
            key = row_key(path, self.root)
            seed = derive_seed(self.seed, key)
            pixels = even_rgb(np.asarray(image))
            code_max = _CODE_MAX.get(pixels.dtype)
            if code_max is None:
                pixels = pixels.astype(np.float32, copy=False)
            sim = simulate(
                self.sensor,
                pixels,
                self.options,
                seed,
                display_referred=code_max is not None,
                code_max=code_max,
            )
            out["key"].append(key)
            out["file_seed"].append(seed)
            out["noisy"].append(Simulation.codes(sim.noisy))
            if self.options.clean:
                out["clean"].append(Simulation.codes(sim.clean))
            out["iso"].append(float(sim.params.iso))
            metadata = capture_metadata(self.sensor, self.options, seed, sim)
            out["metadata"].append(json.dumps(metadata))
        return out
