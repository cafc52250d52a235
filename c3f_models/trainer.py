"""The project's Trainer: Lightning's, plus the ``export`` CLI subcommand and a checkpoint on Ctrl-C."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import lightning as L
from lightning.pytorch.callbacks import Callback

from c3f_models.resume import ExactResume

INTERRUPTED_CKPT = "interrupted.ckpt"


@dataclass(frozen=True)
class Interruption:
    """A run stopped by Ctrl-C: the step it reached and the checkpoint saved there (None if none);
    ``stage``: ``fit``, ``validate``, ``test`` or ``predict`` (only ``fit`` saves a checkpoint)."""

    step: int
    checkpoint: Path | None
    stage: str = "fit"

    def message(self) -> str:
        if self.stage != "fit":
            return f"interrupted during {self.stage}; its results are incomplete, nothing was saved"
        if self.checkpoint is None:
            return f"interrupted at step {self.step}; no checkpoint could be saved"
        return (f"interrupted at step {self.step}; checkpoint saved: {self.checkpoint} "
                f"(resume with --ckpt_path {self.checkpoint})")


class InterruptCheckpoint(Callback):
    """On Ctrl-C during ``fit``, save the run as the interrupt found it to
    ``<checkpoint dir>/interrupted.ckpt`` (written beside, then renamed) so the steps since the
    last checkpoint are not lost. The CLI reads :attr:`last` to print one line."""

    last: ClassVar[Interruption | None] = None

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        if not isinstance(exception, KeyboardInterrupt):
            return
        if trainer.state.fn != "fit":
            stage = str(getattr(trainer.state.fn, "value", trainer.state.fn))
            type(self).last = Interruption(int(trainer.global_step), None, stage)
            return
        folder = Path(getattr(trainer.checkpoint_callback, "dirpath", None) or Path(trainer.default_root_dir))
        path = folder / INTERRUPTED_CKPT
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".interrupted.", suffix=".ckpt", dir=folder)
            os.close(fd)
            trainer.save_checkpoint(tmp, weights_only=False)
            os.replace(tmp, path)
        except Exception:  # noqa: BLE001 -- a failed save must not hide the interrupt
            path = None
        type(self).last = Interruption(int(trainer.global_step), path)


class C3FTrainer(L.Trainer):
    """Lightning Trainer used by ``python -m c3f_models``.

    Extra subcommands of the CLI are methods of this class (LightningCLI calls
    ``trainer.<subcommand>(model=..., datamodule=..., ...)``; see ``EXTRA_SUBCOMMANDS``).
    An :class:`InterruptCheckpoint` and a :class:`c3f_models.resume.ExactResume` (RNG states in
    every checkpoint, for an exact resume) are always among the callbacks.
    """

    def __init__(self, *args: Any, callbacks: Any = None, **kwargs: Any) -> None:
        if callbacks is None:
            callbacks = []
        callbacks = list(callbacks) if isinstance(callbacks, (list, tuple)) else [callbacks]
        for kind in (InterruptCheckpoint, ExactResume):
            if not any(isinstance(c, kind) for c in callbacks):
                callbacks.append(kind())
        super().__init__(*args, callbacks=callbacks, **kwargs)

    def export(
        self,
        model: L.LightningModule,
        datamodule: L.LightningDataModule | None = None,
        ckpt_path: str | None = None,
        output_dir: str = "exported",
        frames: str | None = None,
        num_frames: int = 4,
        tolerance: float | None = None,
        dynamic_size: bool = True,
        weights_only: bool | None = None,
        graphs: list[str] | None = None,
        storage: str = "float32",
        metric_scale: float | None = None,
        precision: str = "float32",
        calibration_frames: int = 32,
    ) -> list[Path]:
        """Export the checkpoint's nets to ONNX with metadata and an onnxruntime parity check.

        Writes ``output_dir/depthnet.onnx`` + ``posenet.onnx`` (DepthNet) or
        ``contrafeat.onnx`` + ``contrafeat_kp.onnx`` (ContraFeat: the dense map, the descriptors at
        given keypoints), and ``export.json``; see :mod:`export`.

        Args:
            ckpt_path: the checkpoint to export (``last.ckpt`` of a ``fit`` run).
            output_dir: folder for the ONNX files.
            frames: sequence folder for the parity frames (default: the data module's first
                test/val/train sequence).
            num_frames: frames compared in the parity check.
            tolerance: the parity bound, above which the export fails: for float32 the largest
                accepted |onnxruntime - PyTorch| of any output element (default 1e-4); for float16
                and int8 the mean absolute difference over the mean magnitude of PyTorch's float32
                output (defaults 5e-3 and 6e-2).
            dynamic_size: height and width as dynamic axes (batch always is).
            weights_only: accepted so that a run's saved ``config.yaml`` (which has it, for
                ``fit``) works; the checkpoint is always read with the safe unpickler
                (``weights_only=True``) and False is refused.
            graphs: only these graphs (``--graphs '[depth]'``: DepthNet without PoseNet, which
                ``c3f_slam`` does not use); names ``depth``, ``pose``, ``descriptors`` (dense map),
                ``descriptors_kp`` (at keypoints). Default all.
            storage: ``float32`` or ``float16`` (weights stored as float16, computation float32:
                half the file size; exact for weights that are float16 values, as the zoo's are).
            metric_scale: record this depth scale to metres instead of measuring it on the
                training data (e.g. after test-time training from a zoo model: its recorded scale).
            precision: the graphs' arithmetic: ``float32``, ``float16`` (for GPUs; no faster on a
                CPU) or ``int8`` (static quantisation calibrated on training frames; 1.3-1.8x
                faster for the zoo's nets on a CPU with VNNI). Inputs and outputs stay float32.
            calibration_frames: training frames that calibrate the int8 activation ranges.
        """
        from export import export_model  # torch.onnx is imported only when exporting

        written = export_model(
            model, ckpt_path, output_dir, datamodule=datamodule, frames=frames, num_frames=num_frames,
            tolerance=tolerance, dynamic_size=dynamic_size, weights_only=weights_only, graphs=graphs, storage=storage,
            metric_scale=metric_scale, precision=precision, calibration_frames=calibration_frames,
        )
        for path in written:
            print(f"wrote {path}")
        return written
