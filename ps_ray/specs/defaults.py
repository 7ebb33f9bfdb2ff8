"""The paper's network sizes, written once: every builder, spec and key takes its defaults here
(docs/authors_code.md)."""

INTERFACE_DIM = 128  # the interface width; for PS the number of anchors
HIDDEN = 256  # hidden units per layer of every MLP
MAX_WIDTH = 8192  # no ps_ray network is wider; a larger size in a spec or file is a mistake
