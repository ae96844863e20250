"""Other engines' integrators as rbstudy schemes, behind optional extras (docs/extending.md).

Each module adapts one engine and defines its schemes as `rbstudy.schemes.Scheme` objects;
the registry loads them as it loads plug-ins (`rbstudy.schemes._plugins.ENGINES`), so that
an engine that is not installed lists its schemes as unavailable, with the install command.
Importing this package loads nothing.
"""
