"""One module per design method; each exposes ``run(family, n_drop, options) -> DesignResult``."""
