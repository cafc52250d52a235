"""Frames on their way in: ``stream`` (a folder or video, prefetched), ``quality`` (the
frame-quality gate: dark, saturated, blurred, repeated), ``tissue`` (the image area that shows
tissue: border and overlays), ``preprocess`` (the one pre-processing chain of every network
input, shared with training)."""
