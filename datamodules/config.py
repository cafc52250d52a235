"""Settings groups of the sequence data modules (:class:`datamodules.base.SequenceDataModule`).

In a config they are nested under ``data.init_args`` (``frames: {size: [128, 128]}``), on the
command line ``--data.frames.size [128, 128]``; in Python a group is a dataclass instance or a
dict of its fields (:func:`c3f_core.settings.as_config`). Each group validates itself in
``__post_init__`` and names the option in its one-line error. Sizes are (width, height) in
pixels; offsets, strides and gaps count frames.
"""

from __future__ import annotations

from dataclasses import dataclass

from c3f_core.errors import InputError

SPLITS = ("train", "val", "test")


def check_stride(stride: int) -> None:
    """InputError unless the frame stride of the samples (``data.sampling.stride``) is >= 1."""
    if stride < 1:
        raise InputError(f"data.sampling.stride must be >= 1, got {stride}")


@dataclass(frozen=True)
class SplitConfig:
    """Which whole sequences train, validate and test.

    With ``train``, ``val`` and ``test`` all null the split is automatic: the data set's published
    one if it has one (its training part shared out by ``val_fraction``), else the fractions of
    the sorted names.

    Attributes:
        train: names of the training sequences; null = automatic.
        val: names of the validation sequences; null = automatic.
        test: names of the test sequences; null = automatic.
        val_fraction: share of the sequences that validate in an automatic split.
        test_fraction: share of the sequences that test in an automatic split (the last names).
    """

    train: tuple[str, ...] | None = None
    val: tuple[str, ...] | None = None
    test: tuple[str, ...] | None = None
    val_fraction: float = 0.1
    test_fraction: float = 0.2

    def __post_init__(self) -> None:
        for name in SPLITS:
            names = getattr(self, name)
            if names is not None:
                object.__setattr__(self, name, tuple(names))
        for name in ("val_fraction", "test_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise InputError(f"data.split.{name} must be in [0, 1], got {value}")

    def names(self) -> dict[str, tuple[str, ...] | None]:
        """The configured names of each split (None where not given)."""
        return {name: getattr(self, name) for name in SPLITS}


@dataclass(frozen=True)
class TupleSamplingConfig:
    """The frames of a sample: the centre frame t and t + offset * stride for each offset.

    Attributes:
        frame_offsets: offsets from the centre frame; must hold 0 (DepthNet needs [-1, 0, 1]).
        stride: multiplies the offsets (the frame gap between neighbours), >= 1.
    """

    frame_offsets: tuple[int, ...] = (-1, 0, 1)
    stride: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame_offsets", tuple(int(o) for o in self.frame_offsets))
        check_stride(self.stride)
        if 0 not in self.frame_offsets:
            raise InputError(
                f"data.sampling.frame_offsets must contain 0 (the centre frame), got {list(self.frame_offsets)}"
            )

    def offsets(self) -> list[int]:
        """Frame offsets from the centre, stride applied, in ``frame_offsets`` order."""
        return [o * self.stride for o in self.frame_offsets]


@dataclass(frozen=True)
class FramesConfig:
    """Pre-processing of every frame (docs/design.md, Pre-processing); the intrinsics follow the crop and the resize.

    Attributes:
        crop: centre crop (width, height), pixels, applied first; null = none.
        size: network input (width, height), pixels, after the crop; null = keep the (cropped) size.
        specular: compute the specular mask (luma > 0.9, 13-px dilation) and inpaint its pixels.
    """

    crop: tuple[int, int] | None = None
    size: tuple[int, int] | None = (224, 224)
    specular: bool = True

    def __post_init__(self) -> None:
        for name in ("crop", "size"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(value))


@dataclass(frozen=True)
class LoaderConfig:
    """The PyTorch data loaders (training shuffles, the others keep the order).

    Attributes:
        batch_size: samples per batch.
        num_workers: loader processes (0 = in the main process; others are kept between epochs).
    """

    batch_size: int = 16
    num_workers: int = 0

    def __post_init__(self) -> None:
        if self.batch_size < 1:
            raise InputError(f"data.loader.batch_size must be >= 1, got {self.batch_size}")
        if self.num_workers < 0:
            raise InputError(f"data.loader.num_workers must be >= 0, got {self.num_workers}")


__all__ = ["SPLITS", "FramesConfig", "LoaderConfig", "SplitConfig", "TupleSamplingConfig", "check_stride"]
