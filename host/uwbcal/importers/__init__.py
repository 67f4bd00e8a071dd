"""Importers: real recordings from other tools converted into uwbcal's session schema.

Each importer turns a source's files into record arrays in the column layout of
:mod:`uwbcal.sessions.columns` plus a metadata dict (provenance, settings, what was lost),
and never guesses silently: a missing, truncated or malformed file is a
:class:`uwbcal.errors.SessionError` naming the file and the line.
"""
