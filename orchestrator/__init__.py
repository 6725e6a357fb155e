"""Line co-simulation: layout -> system structure -> fmpy master -> results.

Split as in libcosim: ``system`` (what is connected to what), ``layout``
(builds a system from a user's YAML), ``master`` (the algorithm that steps
FMUs), ``results`` (observers that record), ``reference`` (the monolithic
model used to measure co-simulation error).
"""
