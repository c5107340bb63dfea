"""Learning guides: trace recording, site networks, training, ONNX export, tuning, rounds."""
