"""Status codes: how a step, a Newton solve or a material update ended.

Failures inside compiled programs are integer codes, never exceptions; the host boundary
(:mod:`jaxform.simulation`, :mod:`jaxform.gradients`) turns them into a smaller step or a
message.  Codes are ordered by severity (larger = worse), so the worst of several is
their maximum.  This module imports nothing, so any layer may use it.
"""

OK = 0
NEWTON_NOT_CONVERGED = 1
LOCAL_SOLVE_FAILED = 2
INVERTED = 3
NOT_FINITE = 4
SINGULAR = 5  # raised by a linear solver (klujax) on the host, not a code inside jit
NO_TEMPERATURE = 6  # a nodal temperature at or below 0 K (a coupled thermal run)

CAUSES = {
    OK: "converged",
    NEWTON_NOT_CONVERGED: "Newton did not converge",
    LOCAL_SOLVE_FAILED: "the local material solve failed",
    INVERTED: "an element inverted (det F <= 0)",
    NOT_FINITE: "the residual is not finite",
    SINGULAR: "the linear solver found the Jacobian singular",
    NO_TEMPERATURE: "a nodal temperature fell to 0 K or below",
}
