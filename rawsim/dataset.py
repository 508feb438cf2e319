"""A ``torch.utils.data.Dataset`` of noisy/clean raw pairs made on the fly from images."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from torch.utils.data import Dataset

from rawsim.api import unprocess
from rawsim.errors import ParameterError, UnsupportedInputError, check_choice
from rawsim.io.images import IMAGE_EXTENSIONS, read_image
from rawsim.isp.levels import normalize_levels
from rawsim.noise.seeds import derive_seed
from rawsim.pipelines.unprocess import image_tensor
from rawsim.run.batch import discover
from rawsim.sensors import MonoSensor, ProfileSensor

LAYOUTS = ("auto", "packed", "mosaic")


class UnprocessDataset(Dataset):
    """Random crops of a folder's images, unprocessed into noisy and clean raws.

    Item ``i`` is drawn from the seed ``derive_seed(seed, epoch, key)`` of its
    image's key (path relative to ``root``): the same index, seed and epoch give
    the same tensors in any worker, process or order. Call :meth:`set_epoch`
    before each epoch for new crops, parameters and noise (DataLoader workers
    copy the dataset when an epoch's iterator starts, so this works with
    ``num_workers > 0`` unless ``persistent_workers`` is set).

    Each item is a dict:

    * ``noisy``, ``clean``: float32, black at 0 and white at 1 (``normalize``) or
      DN; shape (4, S/2, S/2) in R, Gr, Gb, B order (``layout="packed"``, Bayer
      CFAs only) or (1, S, S) (``"mosaic"``: the mosaic as the sensor records it,
      in its CFA, ``sensor.cfa``; a mono sensor always gives (1, S, S));
    * ``iso``, ``gain`` (K, DN/e⁻), ``read_sigma`` (DN): float32 scalars;
    * ``wb_gains`` (3,) and ``xyz_to_camera`` (3, 3): the parameters used;
    * ``index``: the item's index.

    Args:
        root: folder of images (searched recursively, as the CLI does).
        sensor: the sensor simulated.
        crop: crop size S in pixels, even; crops start on whole CFA periods (even
            rows and columns for Bayer, multiples of 6 for X-Trans), so every crop
            has the sensor's CFA phase: its top-left site is the pattern's.
        seed: the dataset's seed.
        iso: one ISO for every item, as for :func:`rawsim.api.unprocess`.
        iso_range: (MIN, MAX), each item's ISO drawn log-uniformly (default,
            with ``iso`` None too: the profile's whole range).
        randomize: sample colour matrix, white balance and brightness per item.
        noise: the noise model, as ``--noise``.
        layout: ``packed``, ``mosaic``, or ``auto`` (default): ``packed`` for a
            Bayer sensor, ``mosaic`` for any other CFA (X-Trans has no 4-plane
            packing) and for mono.
        normalize: scale DN to [0, 1] above black.
    """

    def __init__(
        self,
        root: str | Path,
        sensor: ProfileSensor,
        *,
        crop: int = 256,
        seed: int = 0,
        iso: float | None = None,
        iso_range: tuple[float, float] | None = None,
        randomize: bool = True,
        noise: str = "poisson-gaussian",
        layout: str = "auto",
        normalize: bool = True,
    ) -> None:
        if crop < 2 or crop % 2:
            raise ParameterError(f"crop must be an even number of pixels ≥ 2, got {crop}")
        check_choice("layout", layout, LAYOUTS)
        bayer = not isinstance(sensor, MonoSensor) and sensor.cfa.is_bayer
        if layout == "auto":
            layout = "packed" if bayer else "mosaic"
        elif layout == "packed" and not bayer and not isinstance(sensor, MonoSensor):
            raise ParameterError(
                f"layout 'packed' (R, Gr, Gb, B planes) needs a Bayer CFA; the sensor's "
                f"is {sensor.cfa.name} ({sensor.cfa.period[0]}×{sensor.cfa.period[1]}): "
                "use layout='mosaic' (or 'auto')"
            )
        found, missing, _ = discover([root], IMAGE_EXTENSIONS)
        if missing or not found:
            raise ParameterError(f"{root}: no images found")
        self.files: Sequence[tuple[Path, str]] = found
        self.sensor, self.crop, self.seed, self.epoch = sensor, crop, seed, 0
        if iso is None and iso_range is None:
            iso_range = sensor.profile.iso_range
        self.iso, self.iso_range = iso, iso_range
        self.randomize, self.noise = randomize, noise
        self.layout, self.normalize = layout, normalize
        #: Crops start on multiples of this (rows, columns): the CFA period (2, 2) for mono.
        self.period = (2, 2) if isinstance(sensor, MonoSensor) else sensor.cfa.period

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose crops, parameters and noise the items use."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, index: int) -> dict:
        path, key = self.files[index]
        seed = derive_seed(self.seed, self.epoch, key)
        decoded = read_image(path)
        h, w = decoded.pixels.shape[:2]
        s = self.crop
        if h < s or w < s:
            raise UnsupportedInputError(f"{path}: {w}×{h} is smaller than the {s}×{s} crop")
        top, left = self.crop_origin(h, w, seed)
        # the crop as a view: the kernel reads it in place (int32 only for uint16 codes)
        image = image_tensor(decoded.pixels[top : top + s, left : left + s])
        noisy, clean, meta = unprocess(
            image,
            self.sensor,
            [seed],
            iso=self.iso,
            iso_range=self.iso_range,
            randomize=self.randomize,
            noise=self.noise,
            display_referred=not decoded.is_float,
            code_max=decoded.code_max,
        )
        m = meta[0]
        return {
            "noisy": self._arrange(noisy),
            "clean": self._arrange(clean),
            "iso": torch.tensor(m["iso"], dtype=torch.float32),
            "gain": torch.tensor(m["noise"].get("gain_dn_per_electron", 0.0), dtype=torch.float32),
            "read_sigma": torch.tensor(m["noise"]["read_std_dn"], dtype=torch.float32),
            "wb_gains": torch.tensor(m["params"]["wb_gains"], dtype=torch.float32),
            "xyz_to_camera": torch.tensor(m["params"]["xyz_to_camera"], dtype=torch.float32),
            "index": index,
        }

    def crop_origin(self, height: int, width: int, seed: int) -> tuple[int, int]:
        """(top, left) of the crop an item of ``seed`` takes from a height × width
        image: uniform over the positions on whole CFA periods (:attr:`period`) where
        the crop fits, drawn from ``derive_seed(seed, "crop")``."""
        g = torch.Generator().manual_seed(derive_seed(seed, "crop"))
        (ph, pw), s = self.period, self.crop
        top = ph * int(torch.randint((height - s) // ph + 1, (1,), generator=g))
        left = pw * int(torch.randint((width - s) // pw + 1, (1,), generator=g))
        return top, left

    def _arrange(self, dn: torch.Tensor) -> torch.Tensor:
        """(1, 1, S, S) DN → the item's layout and scale."""
        sensor = self.sensor
        x = normalize_levels(dn, sensor.black_level, sensor.white_level) if self.normalize else dn
        if self.layout == "packed" and not isinstance(sensor, MonoSensor):
            return sensor.cfa.pack(x)[0]
        return x[0]
