"""The inputs layer: the one place that reads YAML or files, and returns checked physics objects.

`reader` (typed values by key path, bounded input files), `yaml_file` (a study or cluster
file -> values), the table files (`text_table`, `node_table`, `load_table`) and the scene
readers (`scenes`, `assembly`, `loads`, their shared `columns`): a ``scene:`` block ->
a `rbstudy.physics.scenes.SceneTable`. Physics never imports it. Importing this package
loads nothing.
"""
