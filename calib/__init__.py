"""Calibration: log readers/writers, simulators, ground truth, labelling, the fits and the validation scores."""

__version__ = "0.1.0"


def _register_parameter_models() -> None:
    from calib.provenance import register

    register()


_register_parameter_models()
