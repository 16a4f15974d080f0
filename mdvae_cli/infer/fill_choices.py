"""The ways a hole can be filled (``infer.fill``), named where the command line can read them
without loading the model."""

FILLS = ("curve", "model", "off")
#: what ``mdvae denoise`` fills with (``--fill on``)
DEFAULT_FILL = "curve"
