"""The jobs the command line runs, each composed from the layers below.

``compare`` (fit every configured family on every fold, judge, choose, report), ``fleet``
(the same per unit of a fleet, in parallel, with limits and outliers), ``calibrate`` (a
flight log in, autopilot parameters out) and ``info`` (what a data file holds).  Only
:mod:`thermonet.api` and :mod:`thermonet.cli` sit above them.
"""
