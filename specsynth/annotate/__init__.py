"""The annotation engine: masks, depth, visibility, boxes and poses from the rasteriser; albedo, normal and NOCS maps."""
