"""Cameras and what they see: pose sampling, the sensor model, photometric augmentation, scene previews."""
