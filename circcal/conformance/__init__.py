"""circcal's conformance suite, installed with the package: check any calibrator against circcal's solver and the
truth from any folder::

    python -m pytest --pyargs circcal.conformance --calibrator mypkg.mymodule:calibrate
    python -m pytest --pyargs circcal.conformance --calibrator mycal.py:calibrate --conformance-full
    circcal conformance --calibrator mypkg.mymodule:calibrate

The hooks, options and fixtures are the ``circcal`` pytest plug-in's (:mod:`circcal.validators.pytest_plugin`,
entry point ``pytest11``); the cases and bounds are :mod:`circcal.validators.case_matrix`, their checks
:mod:`circcal.validators.case_run`. What a calibrator is, and how it declares the model it fits (``lens``, ``fixes``),
is in docs/validation.md.
"""
