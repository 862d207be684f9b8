"""What a run leaves for a reader: ``results.json``'s schema, the plots and ``report.html``.

:mod:`thermonet.reporting.results` defines the result document, :mod:`thermonet.reporting.plots`
draws the figures (matplotlib, loaded when drawing) and :mod:`thermonet.reporting.report`
writes the self-contained HTML report.  It sits beside :mod:`thermonet.exporting`, above the
training layer, and is used by the workflows.
"""
