"""The options that say what a run reads and with which models, shared by ``python -m c3f_slam
run`` and ``batch`` (:mod:`c3f_slam.cli.main`, :mod:`c3f_slam.batch.cli`), and what they give: the
settings tree (:func:`settings_from_args`) and the :class:`c3f_slam.pipeline.RunInputs`
(:func:`inputs_from_args`). Nothing heavy is imported until a command runs."""

from __future__ import annotations

import argparse

from c3f_core.errors import InputError

#: ``--threads``' help in ``run``
RUN_THREADS_HELP = "onnxruntime threads per model (default: the cores less one, at least 1)"


def add_input_options(r: argparse.ArgumentParser, threads_help: str = RUN_THREADS_HELP) -> None:
    """Depth and descriptor sources, the models, the camera of a video (``--camera`` or the guess
    ``--fov``), onnxruntime threads and providers, the depth scale, ``--max-bad-frames``."""
    r.add_argument("--depth-source", choices=("files", "model"),
                   help="files: depth/ of the sequence (RGB-D mode); model: DepthNet ONNX (--depth-model). "
                        "Default: model when --depth-model is given, else files")
    r.add_argument("--descriptors", choices=("sift", "contrafeat"),
                   help="sift (the SIFT baseline) or contrafeat (ONNX, --feature-model). "
                        "Default: contrafeat when --feature-model is given, else sift")
    r.add_argument("--depth-model", help="DepthNet ONNX export (see `python -m c3f_slam inspect`), or zoo:NAME "
                                         "(a model of the repository's zoo/, `python -m c3f_models zoo list`)")
    r.add_argument("--feature-model", help="ContraFeat ONNX export (descriptors at the SIFT keypoints), or zoo:NAME")
    lens = r.add_mutually_exclusive_group()
    lens.add_argument("--camera", help="camera.json of a video (default: camera.json beside the video; make one with "
                                       "`python -m c3f_slam calibrate`); a distorted lens (pinhole distortion "
                                       "coefficients, fisheye, or omnidirectional as C3VD publishes it) is "
                                       "undistorted to a pinhole camera")
    lens.add_argument("--fov", type=float, metavar="DEG",
                      help="no calibration: guess a pinhole camera of DEG degrees horizontal field of view for a "
                           "video (summary.json camera_source says it is a guess)")
    r.add_argument("--threads", type=int, default=None, help=threads_help)
    r.add_argument("--providers", default="CPUExecutionProvider",
                   help="onnxruntime execution providers of the models, comma-separated, preferred first, e.g. "
                        "CUDAExecutionProvider,CPUExecutionProvider (CUDA needs the onnxruntime-gpu package); "
                        "default CPUExecutionProvider")
    r.add_argument("--depth-scale", type=float,
                   help="multiply the --depth-model depth by this factor (self-supervised depth is known up to "
                        "a scale, the thresholds are in metres); default: the factor the exporter measured on the "
                        "training data (metadata depth.metric_scale), else 1")
    r.add_argument("--max-bad-frames", type=int,
                   help="unreadable frames (missing or corrupt files, undecodable video frames) skipped and counted "
                        "(summary.json skipped_unreadable); one more fails the run (default 10)")


def settings_from_args(args: argparse.Namespace):
    """The run's settings tree (preset, --config, --set) and the replayed summary, if any."""
    from c3f_slam.config.loading import read_config_file, resolve_config

    config = read_config_file(args.config) if args.config else None
    return resolve_config(args.preset, config, args.set), (config.record if config else None)


def inputs_from_args(args: argparse.Namespace, threads: int | None = None):
    """The :class:`c3f_slam.pipeline.RunInputs` of the options (``threads``: instead of ``--threads``).
    InputError for ``--threads`` below 1, an unknown provider or a ``--fov`` out of range."""
    from c3f_slam.camera.intrinsics import FovGuess
    from c3f_slam.models.session import check_providers  # onnxruntime, Open3D, OpenCV: not for --print-config
    from c3f_slam.pipeline import RunInputs

    if args.threads is not None and args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    camera = FovGuess(args.fov) if args.fov is not None else args.camera
    given = {} if args.max_bad_frames is None else {"max_bad_frames": args.max_bad_frames}  # else RunInputs'
    return RunInputs(descriptors=args.descriptors, depth_source=args.depth_source, depth_model=args.depth_model,
                     feature_model=args.feature_model, camera=camera, threads=threads or args.threads,
                     depth_scale=args.depth_scale, providers=check_providers(args.providers), **given)


__all__ = ["RUN_THREADS_HELP", "add_input_options", "inputs_from_args", "settings_from_args"]
