"""Methods that cover the network builder's code paths, for tests parametrized over methods."""

# One method per code path of the network builder: the presets, and variants that reach what no
# preset does (centring + LayerNorm; the penalties with raw-latent critics; consolidation of a
# projection that trains switched on).
CODE_PATHS = (
    "ps",
    "ps_distilled",
    "ablation",
    "devin",
    "devin_large",
    "plain",
    "ps+center=standard+norm=layer",
    "ps+norm=layer+norm_reg=1+ref_weight=0.1+relative_critics=false",
    "ps+consolidate=true+relative_critics=false+scale=0.25",
)

# consolidation of a projection that is on while it trains (the old row ps_consolidated)
PS_CONSOLIDATED = (
    "ps+consolidate=true+norm=layer+norm_reg=1+ref_weight=0.03+relative_critics=false+scale=0.25"
)
