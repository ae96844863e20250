"""The verbs of the ``rbstudy`` command (`rbstudy.cli`), a module per kind: `study` reads
configs (sweep, validate), `results` reads archives (summary, plot, report, verify),
`schemes` is about the schemes themselves (schemes, bench, conformance); `arguments`
declares every verb's options and `common` holds what they share. Each verb takes the
parsed arguments and returns its exit code; a verb imports what it needs when it runs, so
that parsing the command loads nothing heavy."""
