"""Inputs and outputs: image decoding, stereo frame pairing, base poses, output fields."""
