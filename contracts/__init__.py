"""The typed contracts every layer shares, at the bottom of the house: it imports no project package.

:mod:`contracts.settings` (the one ``Settings``), :mod:`contracts.jobs` (kinds, statuses, payloads),
:mod:`contracts.queries` (query parameters), :mod:`contracts.answers` (the answer models),
:mod:`contracts.references` (the stored-reference format) and :mod:`contracts.api` (the HTTP API's request and
response models, which the service answers with and the client parses).
"""
