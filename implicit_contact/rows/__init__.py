"""The rows of one geometrically implicit step ([GI] eqs 15-22, 28-32, 33-55), as compiled kernels.

Each module holds one part of the paper, its residual and its Jacobian side by side:

    bodies.py     poses at l+1 as functions of the velocity unknowns ([GI] eq 21, second line)
    contact.py    a pair's rows: closest-point KKT, gap, friction with torsion ((15)-(22),
                  (28)-(32)), the quasi-rigid layer and core ((33)-(55)), and the pair's
                  generalized impulses on its bodies
    support.py    2.5D support friction of a planar body (implicit_contact/support.py)
    dynamics.py   the Newton-Euler rows of the skeletons ([GI] eq 21, first line)
    assemble.py   F and J of a whole step from the rows above (dense, or a fixed sparse pattern)

They work on flat arrays (the step's tables, built by formulation.StepProblem), never on Python
objects, and run as plain Python under NUMBA_DISABLE_JIT=1 (see implicit_contact/_jit.py).
"""
