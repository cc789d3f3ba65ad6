"""The typed contracts every layer shares, at the bottom of the house: it imports no project package.

:mod:`contracts.settings` (the one ``Settings``), :mod:`contracts.jobs` (kinds, statuses, payloads),
:mod:`contracts.queries` (query parameters), :mod:`contracts.answers` (the answer models) and
:mod:`contracts.references` (the stored-reference format).
"""
