"""Settings of the input frames: which are read (:class:`FramesConfig`), which carry nothing
(:class:`FrameQualityConfig`, :mod:`c3f_slam.frames.quality`) and which part of each shows tissue
(:class:`TissueConfig`, :mod:`c3f_slam.frames.tissue`). Each group checks its own fields."""

from __future__ import annotations

from dataclasses import dataclass, field

from c3f_slam.config.checks import at_least, check


@dataclass(frozen=True)
class FrameQualityConfig:
    """Settings of the frame-quality gate (``frames.quality.*``). Luma is 0..255 (BT.601),
    shares are fractions of the mask's pixels, sizes are thumbnail pixels."""

    enabled: bool = True  #: False: every frame is "ok" (measures are still computed)
    #: long side (px) of the thumbnail every measure but the duplicate ones uses (the frame shrunk
    #: by a whole factor): 160 keeps a Gaussian blur of 1.5 px at 446 px measurable (ratio ~0.4 on
    #: a real phantom clip) while a 640x480 frame costs under 1 ms
    thumb_size: int = 160
    #: long side (px) of the thumbnail the duplicate measures use: at 64 px compression noise is
    #: mostly averaged out while motion keeps its size
    duplicate_size: int = 64
    #: the sharpness reference: median of the last this many accepted frames (it follows the
    #: content: with 15, a close-up approached over 13 frames of a 256-px simulated sequence was
    #: taken for blur, 11 false flags against 10 true; with 5, none, and the same 10 true)
    reference_frames: int = 5
    #: accepted frames needed before "blurred" can fire (no reference, no blur)
    min_reference: int = 5
    #: sharpness / reference below this: blurred. Sharpness is the detail of the finest octave
    #: over the next one's, in the direction that has the least
    #: (:func:`c3f_slam.frames.quality._sharpness`), so it hardly depends on the amount of texture:
    #: sharp frames of six simulated sequences gave ratios of 0.72-1.77 and a real phantom clip
    #: >= 0.89, a Gaussian blur of 1.5 thumbnail px 0.18-0.30 (on the 446-px phantom frames that
    #: is a blur of about 4.5 px; 1.5 px there passes)
    blur_ratio: float = 0.5
    #: thumbnail pixels at least this bright (luma), and their 5x5 neighbours, are left out of the
    #: sharpness: a large specular highlight carries its edge into the coarser octave, so a wet view
    #: full of them measured as blurred (seq5 of the simulator, a camera pulling back from a
    #: close-up: 5-6 sharp frames in a row at 0.40-0.50 of the reference; left out, none, and the
    #: simulator's motion blur still flagged: 19 of 23 blurred frames against 17 before). 255: off
    blur_highlight_level: float = 230.0
    #: this many blurred frames in a row (no frame accepted between): the content changed (e.g.
    #: a smooth close-up), not the focus; the reference restarts from the next frames
    reference_reset: int = 30
    #: luma below which a pixel is dark; a frame is dark when at least dark_share of the mask
    #: is (a lumen alone, the dark hole, covers well under half the view; a phantom clip at 1/5 of
    #: its exposure, mean luma 23, is dark)
    dark_level: float = 40.0
    dark_share: float = 0.75  #: ... and at least this share of the mask dark: a dark frame
    #: a pixel is washed out when its luma reaches this (saturated white, not a saturated red
    #: channel, which lit mucosa often has); a frame when at least washed_share of the mask is
    washed_level: float = 245.0
    washed_share: float = 0.4  #: ... and at least this share of the mask washed out: a washed-out frame
    #: a frame is a duplicate of the last accepted one (or of the last rejected picture) when, at
    #: duplicate_size px inside the mask, the part of their difference that local motion explains
    #: is below duplicate_motion (rms, luma) and the whole difference below duplicate_luma (mean
    #: |diff|, luma). Measured: a JPEG re-encode at quality 70 leaves motion <= 0.2 (mean |diff| <=
    #: 0.6), a quarter-pixel shift of a 192 px frame 0.7, a half-pixel shift at 640 px 0.35; on a
    #: 60 fps phantom clip (a new picture every 3 to 4 frames) the repeats stay <= 0.19 and every
    #: new picture is >= 0.52. Slower motion is flagged, does not move the reference and so adds
    #: up until a frame passes (at 640 px, below about 0.4 px per frame: every second or third)
    duplicate_motion: float = 0.3
    duplicate_luma: float = 1.5  #: ... and the mean |difference| (luma) below this: a duplicate
    #: a frame is also a duplicate when its motion is below this share of the median motion of the
    #: last reference_frames accepted frames (each against the one accepted before it); 0 = off.
    #: Compression noise does not scale with a frame's size as motion does: the simulator's repeats
    #: (JPEG quality 85) leave motion 0.23-0.66 at 128 px, where its frames move 1.5 and more. On
    #: the phantom clip every new picture moves >= 0.40 of that median and the repeats <= 0.27
    duplicate_motion_share: float = 0.25
    #: a specular highlight: at least this much brighter (luma) than its 5x5 opening and at least
    #: highlight_level bright; "covered" when at least covered_share of the mask lies within
    #: thumb_size / 20 px of one (many small highlights spread over the view: bubbles). The
    #: simulator's wet mucosa puts up to 0.82 of the view near a highlight (256 px), 60 small
    #: drawn bubbles on a 192-px view 0.77, 150 of them 0.97: only a view nearly all covered is
    #: skipped
    highlight_contrast: float = 40.0
    highlight_level: float = 160.0  #: ... and at least this bright (luma): a highlight
    covered_share: float = 0.9  #: share of the mask near a highlight that makes a frame covered (bubbles)

    def __post_init__(self) -> None:
        name = "frames.quality."
        check(isinstance(self.enabled, bool), f"{name}enabled must be true or false, got {self.enabled!r}")
        at_least(self.thumb_size, 32, name + "thumb_size")
        at_least(self.duplicate_size, 8, name + "duplicate_size")
        check(self.duplicate_size <= self.thumb_size,
              f"{name}duplicate_size must be <= thumb_size ({self.thumb_size}), got {self.duplicate_size}")
        at_least(self.reference_frames, 1, name + "reference_frames")
        at_least(self.min_reference, 1, name + "min_reference")
        check(self.min_reference <= self.reference_frames,
              f"{name}min_reference must be <= reference_frames ({self.reference_frames}), got {self.min_reference}")
        _fraction(self.blur_ratio, name + "blur_ratio")
        _luma(self.blur_highlight_level, name + "blur_highlight_level")
        at_least(self.reference_reset, 1, name + "reference_reset")
        _luma(self.dark_level, name + "dark_level")
        _fraction(self.dark_share, name + "dark_share")
        _luma(self.washed_level, name + "washed_level")
        _fraction(self.washed_share, name + "washed_share")
        at_least(self.duplicate_motion, 0.0, name + "duplicate_motion")
        at_least(self.duplicate_luma, 0.0, name + "duplicate_luma")
        check(0.0 <= self.duplicate_motion_share < 1.0,
              f"{name}duplicate_motion_share must be in [0, 1) (0 = off), got {self.duplicate_motion_share}")
        _luma(self.highlight_contrast, name + "highlight_contrast")
        _luma(self.highlight_level, name + "highlight_level")
        _fraction(self.covered_share, name + "covered_share")


def _fraction(value: float, name: str) -> None:
    check(0.0 < value <= 1.0, f"{name} must be in (0, 1], got {value}")


def _luma(value: float, name: str) -> None:
    check(0.0 <= value <= 255.0, f"{name} must be a luma in [0, 255], got {value}")


@dataclass(frozen=True)
class FramesConfig:
    """Which frames of the input a run reads (frames of the sequence or video, in order), and
    how far ahead of the back-end they are read and perceived."""

    stride: int = 1  #: every k-th frame
    max_frames: int | None = None  #: at most this many of them; None = all
    #: frames read and perceived (depth, keypoints, descriptors) ahead of the back-end by a worker
    #: thread, overlapping it; 0 = one after another in the run loop. Same results either way
    prefetch: int = 2
    #: threads that perceive frames at once (with prefetch >= 1; at most prefetch + 1 are busy):
    #: the networks and SIFT of the next frames overlap each other as well as the back-end.
    #: Same results with any number
    perception_workers: int = 2
    #: frames that carry nothing (blurred, dark, washed out, covered, repeated) are skipped
    quality: FrameQualityConfig = field(default_factory=FrameQualityConfig)

    def __post_init__(self) -> None:
        at_least(self.stride, 1, "frames.stride")
        at_least(self.max_frames, 1, "frames.max_frames", "all frames")
        at_least(self.prefetch, 0, "frames.prefetch")
        at_least(self.perception_workers, 1, "frames.perception_workers")


TISSUE_MODES = ("auto", "off")


@dataclass(frozen=True)
class TissueConfig:
    """The image area that shows tissue (:mod:`c3f_slam.frames.tissue`): the scope's black border and
    burned-in overlays are left out of depth, keypoints, fusion and the unseen-wall estimate.
    Luma levels are 0..255."""

    #: auto: ``file``, else the mask camera.json names (``tissue_mask``), else detected from the
    #: first frames; off: the whole frame
    mode: str = "auto"
    file: str | None = None  #: mask image (PNG of the frame size, white = tissue); None: see ``mode``
    frames: int = 40  #: frames sampled for detection
    window: int = 300  #: ... evenly over the first this many frames of the run (5 s of 60 fps video)
    dark_level: float = 30.0  #: a pixel no sample shows brighter than this is border
    static_level: float = 3.0  #: a change of luma up to this between two samples is compression noise
    #: a pixel changing between at least this share of consecutive samples moves with the scene
    moving_share: float = 0.3
    overlay_edge: float = 120.0  #: Sobel magnitude of the temporal median at a static overlay's edge
    margin: float = 0.015  #: the mask is eroded by this share of the smaller image side
    full_share: float = 0.995  #: a mask covering at least this share of the frame: no border

    def __post_init__(self) -> None:
        check(self.mode in TISSUE_MODES, f"tissue.mode must be one of {TISSUE_MODES}, got {self.mode!r}")
        at_least(self.frames, 2, "tissue.frames")
        at_least(self.window, 2, "tissue.window")
        for name in ("dark_level", "static_level", "overlay_edge", "margin"):
            at_least(getattr(self, name), 0.0, f"tissue.{name}")
        check(0.0 < self.moving_share <= 1.0, f"tissue.moving_share must be in (0, 1], got {self.moving_share}")
        check(0.0 < self.full_share <= 1.0, f"tissue.full_share must be in (0, 1], got {self.full_share}")
        check(self.margin < 0.25, f"tissue.margin must be < 0.25, got {self.margin}")
