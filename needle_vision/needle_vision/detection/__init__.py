"""Detection in each image: background model and contrast threshold, image centerlines, curves."""
