"""The simulated bench: stereo endoscope, projector, deforming tissue and trocar with ground truth."""
