"""The camera: ``intrinsics`` (pinhole and lens distortion, following crops and resizes; camera.json),
``omnidirectional`` (the Scaramuzza lens and its undistortion to a pinhole), ``calibration``
(``calibrate`` from checkerboards, undistortion maps, a field-of-view guess), ``frustum`` (which
map blocks a camera sees)."""
