"""Calibration: log readers/writers, the park simulator, ground truth, fits, reports and the CLI."""

__version__ = "0.1.0"


def _register_parameter_models() -> None:
    from calib.provenance import register

    register()


_register_parameter_models()
