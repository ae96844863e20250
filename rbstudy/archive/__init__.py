"""The archive layer: a study's folder on disk (`folder.StudyFolder`), its part files, the
archive written from them and read back, their checksums and provenance, and the one table of
output variables (`variables`), metadata only.

It never imports the sweep (`rbstudy.pipeline`) and never loads numba: a worker that writes a
part, and every command that reads an archive, need this layer alone. Importing this package
loads nothing.
"""
