"""Migration of profiles written under an earlier schema to the current one (:data:`profiles.profile.SCHEMA_VERSION`).

A profile once written loads in every later detcal: a document of an earlier
schema is first validated as what it says it is (a schema-1 document that
uses a schema-2 field is refused by name), then taken through one step per
schema version, ``MIGRATIONS[n]`` turning a valid schema-n document into a
schema-(n + 1) one, and validated again. What each step changes:

- **1 -> 2**: nothing but the number. Every field schema 2 added is optional and
  its default means the schema-1 behaviour (binned P_D, Poisson clutter with a
  uniform density, the chi-square Hotelling threshold, no sensor spread).
- **2 -> 3**: nothing but the number. Schema 3 added ``provenance.commit`` and
  ``provenance.packages``, which the migrated profile leaves unknown (null and
  empty: no migration can say which build made an old profile), and changed how a
  profile is *written*: a unit comment after every quantity, fitted figures to
  six significant digits (a relative change below 1e-5,
  :data:`profiles.store.SAME_REL_TOL`) and the P_D table one bin per line.

The recorded provenance (inputs, command, parameters, creation time, seed) is
kept as recorded: parameters an earlier build did not record (such as
``parameters.landmarks`` before calibrations recorded where the landmarks came
from) stay unrecorded rather than guessed.

Loading an old profile says so in one line, through the listeners registered
with :func:`profiles.notices.on_notice` (the CLI prints it as a warning); ``detcal profile
migrate FILE`` writes the migrated profile to a new file.
"""

from __future__ import annotations

from collections.abc import Callable

from profiles.notices import notice


def notify(where: str, old: int, new: int) -> None:
    """Tell the listeners, in one line, that the profile ``where`` of schema ``old`` was migrated to ``new``."""
    line = (
        f"{where}: profile schema {old} migrated to schema {new} on loading (its content unchanged); "
        f"`detcal profile migrate {where}` writes it as schema {new}"
    )
    notice(line)


def _1_to_2(doc: dict) -> dict:
    # every schema-2 field is optional with the schema-1 meaning as its default: nothing to fill in
    return {**doc, "schema_version": 2}


def _2_to_3(doc: dict) -> dict:
    # provenance.commit and .packages stay unknown (defaults null and {}); the written form is the writer's business
    return {**doc, "schema_version": 3}


#: step n: a valid schema-n document (as :meth:`DetectorProfile.model_dump` gives it, mode json) -> schema n + 1
MIGRATIONS: dict[int, Callable[[dict], dict]] = {1: _1_to_2, 2: _2_to_3}


def migrate_document(doc: dict, to: int) -> dict:
    """``doc`` (a valid document of schema ``doc["schema_version"]``) taken through the steps up to schema ``to``."""
    version = int(doc["schema_version"])
    while version < to:
        doc = MIGRATIONS[version](doc)
        if doc["schema_version"] != version + 1:  # a step that forgot its number would loop or skip
            raise AssertionError(f"migration step {version} wrote schema_version {doc['schema_version']}")
        version += 1
    return doc
