"""FMU sources: one thin pythonfmu script per primitive element, and the builder.

Each script's module name (``webline_<element>``) is unique in a process:
pythonfmu imports FMU scripts by module name into the host's interpreter.
"""
