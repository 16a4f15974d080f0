"""The ways a hole can be filled (``infer.fill``), named where the command line can read them
without loading the model."""

FILLS = ("curve", "learned", "model", "off")
#: what ``mdvae denoise`` fills with (``--fill on``); with networks that read holes it is
#: "learned" (:func:`fill_for`)
DEFAULT_FILL = "curve"


def fill_for(fill: str, reads_holes: bool) -> str:
    """The fill a denoise runs: the default "curve" becomes "learned" for networks fitted to
    read holes (``DenoiserConfig.reads_holes``); any other choice as it is."""
    return "learned" if fill == DEFAULT_FILL and reads_holes else fill
