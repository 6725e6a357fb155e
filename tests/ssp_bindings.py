"""The bindings of an SSD as one fmpy parameter set (``<component>.<name>``): what
``fmpy.ssp.simulation.simulate_ssp`` expects, since it does not apply the SSD's own bindings."""


def full_parameter_set(ssp, validate=False):
    """(ssd, ParameterSet) with every parameter binding of the SSD in ``ssp``."""
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd
    ssd = read_ssd(str(ssp), validate=validate)
    ps = ParameterSet(name="bindings")
    for c in ssd.system.elements:
        for b in c.parameterBindings:
            for s in b.parameterValues:
                for p in s.parameters:
                    q = Parameter(name=f"{c.name}.{p.name}")
                    q.type, q.value = p.type, p.value
                    ps.parameters.append(q)
    return ssd, ps
