"""Learning guides: trace recording, site networks, training, ONNX export, the worker pool."""
