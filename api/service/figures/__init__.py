"""The figures of an axis, for the REST plot endpoints and the dashboard alike.

- :mod:`api.service.figures.axis`: which figure, from which stored results (:func:`render`);
- :mod:`api.service.figures.plots`: arrays to PNG bytes, after the seed paper's figures;
  :mod:`api.service.figures.prognosis`, the prognosis figure beside them;
- :mod:`api.service.figures.cache`: the rendered PNGs, one cache for every reader;
- :mod:`api.service.figures.process`: renders in a worker process, so a plot does not hold the
  service's interpreter.
"""
