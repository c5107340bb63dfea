"""Target datasets: glyphs, silhouettes, scribbles; building, contact sheets."""
