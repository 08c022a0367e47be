"""Designs of experiments and robustness studies (``jaxform study``, docs/doe.md).

* :mod:`~jaxform.study.spec`     the ``[study]`` section: inputs, plan, responses, checks
* :mod:`~jaxform.study.plans`    Latin hypercube, Sobol, Monte Carlo, factorial; inverse CDFs
* :mod:`~jaxform.study.engine`   samples as Dask tasks (local processes or a cluster), the table
* :mod:`~jaxform.study.gradients` exact gradients of the responses (the design machinery)
* :mod:`~jaxform.study.batched`  B samples as one vmapped program (jaxform.batch)
* :mod:`~jaxform.study.analysis` sensitivities (standardized regression, correlation) and plots

This package does not print and does not import the command line.
"""
