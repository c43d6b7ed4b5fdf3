"""What a trained run produces: rendered frames, videos and induced tracks, PLY export."""
