"""The project's Trainer: Lightning's, plus the ``export`` CLI subcommand."""

from __future__ import annotations

from pathlib import Path

import lightning as L


class C3FTrainer(L.Trainer):
    """Lightning Trainer used by ``python -m c3f_models``.

    Extra subcommands of the CLI are methods of this class (LightningCLI calls
    ``trainer.<subcommand>(model=..., datamodule=..., ...)``; see ``EXTRA_SUBCOMMANDS``).
    """

    def export(
        self,
        model: L.LightningModule,
        datamodule: L.LightningDataModule | None = None,
        ckpt_path: str | None = None,
        output_dir: str = "exported",
        frames: str | None = None,
        num_frames: int = 4,
        tolerance: float = 1e-4,
        dynamic_size: bool = True,
        weights_only: bool | None = None,
    ) -> list[Path]:
        """Export the checkpoint's nets to ONNX with metadata and an onnxruntime parity check.

        Writes ``output_dir/depthnet.onnx`` + ``posenet.onnx`` (DepthNet) or
        ``contrafeat.onnx`` (ContraFeat), and ``export.json``; see :mod:`export`.

        Args:
            ckpt_path: the checkpoint to export (``last.ckpt`` of a ``fit`` run).
            output_dir: folder for the ONNX files.
            frames: sequence folder for the parity frames (default: the data module's first
                test/val/train sequence).
            num_frames: frames compared in the parity check.
            tolerance: largest accepted |onnxruntime - PyTorch| of any output element; the
                export fails above it.
            dynamic_size: height and width as dynamic axes (batch always is).
            weights_only: accepted so that a run's saved ``config.yaml`` (which has it, for
                ``fit``) works; the checkpoint is always read with the safe unpickler
                (``weights_only=True``) and False is refused.
        """
        from export import export_model  # torch.onnx is imported only when exporting

        written = export_model(
            model, ckpt_path, output_dir, datamodule, frames, num_frames, tolerance, dynamic_size, weights_only
        )
        for path in written:
            print(f"wrote {path}")
        return written
