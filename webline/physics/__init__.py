"""Physics of the primitive elements, as plain functions (standard library only).

Equation numbers {n} refer to Branca, Pagilla & Reid, *Modeling and
Identification of the Source of Oscillations in Web Tension*. All quantities
are SI: m, s, N, kg, rad. These functions serve the FMUs and the monolithic
reference model alike, so the two can only differ in how they are integrated.
"""
