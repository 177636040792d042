"""Inputs and outputs: MCAP bag reading, image decoding, stereo frame pairing, base poses, output fields, installed
package files."""
