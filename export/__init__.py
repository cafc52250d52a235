"""ONNX export of the trained networks (see the export issue)."""
