"""Test-wide set-up: float64, the one documented switch (jaxform.precision)."""

import jaxform

jaxform.enable_x64()
