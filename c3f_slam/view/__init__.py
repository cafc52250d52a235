"""What a person looks at: the 3D view of a run folder and its videos (``python -m c3f_slam view OUT``).

:mod:`.scene` gathers the layers from a run folder (:mod:`.layers`: meshes, paths, keyframes,
ground truth, components), decimated to a :mod:`.budget`; :mod:`.page` writes the self-contained
HTML around ``viewer.js`` and the vendored three.js (``vendor/``); :mod:`.raycast` renders a
mesh offscreen on the CPU (Open3D ``RaycastingScene``), which :mod:`.rerender` (the input beside
the reconstruction from each estimated pose) and :mod:`.flythrough` (along the smoothed path)
turn into H.264 videos (:mod:`.video`); :mod:`.build` writes the files, :mod:`.command` is the
command. Lengths are metres. Submodules are imported where used (Open3D, OpenCV are heavy).
"""
