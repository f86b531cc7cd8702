"""Writers of baked results and previews: one module per format (USD stage, PLY sequence, video)."""
