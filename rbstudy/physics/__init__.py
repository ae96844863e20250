"""The physics layer: scenes, closed forms, error measures, references and `simulate`.

`scenes`, `quaternions`, `analytic` and `metrics` are numpy/scipy only; `simulate` and
`references` run the compiled schemes. Importing this package loads nothing.
"""
