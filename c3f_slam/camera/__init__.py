"""The camera: ``intrinsics`` (pinhole and lens distortion, following crops and resizes),
``calibration`` (``calibrate`` from checkerboards, undistortion maps, a field-of-view guess),
``frustum`` (which map blocks a camera sees)."""
