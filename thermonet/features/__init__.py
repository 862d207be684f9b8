"""What a drift model reads and what it predicts: the third layer, above :mod:`thermonet.data`.

Feature names and their signals, references and matrices (:mod:`thermonet.features.inputs`),
the dynamic inputs — rate, lag and play, the one definition the exported runtime and the C
code are checked against (:mod:`thermonet.features.dynamics`) — and the targets each output
is fitted to (:mod:`thermonet.features.target`) are torch-free, so a config is checked
against them before torch loads; :mod:`thermonet.features.module` evaluates the features
inside the exported torch graph.
"""
