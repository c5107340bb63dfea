"""Images: rasterizing primitives, guide features, rendering, target masks."""
