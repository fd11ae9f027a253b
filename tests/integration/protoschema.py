# SPDX-License-Identifier: GPL-3.0-or-later
"""The protocol's JSON Schemas (proto/schema, proto/mqtt), checked with
python3-jsonschema (Debian's, draft 2020-12): every file is a valid
schema whose every keyword the draft defines (a misspelt keyword would
otherwise be ignored, and check nothing), and a value is checked against
"FILE#/pointer" with the files' references to each other
("common.json#/$defs/job") resolved among them."""
import json
import os

import jsonschema


class SchemaSet:
    def __init__(self, directory):
        self.dir = os.path.realpath(directory)
        self.base = "file://" + self.dir + "/"
        self.files = {}
        for name in sorted(os.listdir(self.dir)):
            if name.endswith(".json"):
                with open(os.path.join(self.dir, name)) as f:
                    self.files[name] = json.load(f)
        for name, schema in self.files.items():
            try:
                jsonschema.Draft202012Validator.check_schema(schema)
            except jsonschema.SchemaError as e:
                raise ValueError(f"{name}: not a valid JSON Schema: {e.message}") from e
            unknown(schema, name)
        self.store = {self.base + name: schema for name, schema in self.files.items()}

    def errors(self, value, ref):
        """Every violation of value against ref ("FILE#/pointer"), one line
        each: where in the value ($.a.b[2]) and what is wrong."""
        file, _, pointer = ref.partition("#")
        if file not in self.files:
            raise KeyError(f"{ref}: no schema {file} in {self.dir}")
        resolver = jsonschema.RefResolver(self.base + file, self.files[file], store=self.store)
        validator = jsonschema.Draft202012Validator({"$ref": f"{self.base}{file}#{pointer}"},
                                                    resolver=resolver)
        return [f"{where(e.absolute_path)}: {e.message}"
                for e in sorted(validator.iter_errors(value), key=lambda e: list(map(str, e.absolute_path)))]


def where(path):
    out = "$"
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else f".{p}"
    return out


# The keywords that are no assertion: identifiers and annotations.
ANNOTATIONS = {"$schema", "$id", "$defs", "$comment", "$anchor", "title", "description",
               "default", "examples", "deprecated", "readOnly", "writeOnly"}
KEYWORDS = set(jsonschema.Draft202012Validator.VALIDATORS) | ANNOTATIONS
SCHEMA_MAPS = ("properties", "$defs", "patternProperties", "dependentSchemas")
SCHEMA_LISTS = ("oneOf", "anyOf", "allOf", "prefixItems")
SCHEMA_ONE = ("items", "additionalProperties", "not", "if", "then", "else", "contains",
              "propertyNames", "unevaluatedItems", "unevaluatedProperties")


def unknown(s, where):
    """Raises on a keyword draft 2020-12 does not define, anywhere in s."""
    if not isinstance(s, dict):
        return
    for k, v in s.items():
        if k not in KEYWORDS:
            raise ValueError(f"{where}: {k!r} is no JSON Schema 2020-12 keyword")
        if k in SCHEMA_MAPS:
            for name, sub in v.items():
                unknown(sub, f"{where}/{k}/{name}")
        elif k in SCHEMA_LISTS:
            for i, sub in enumerate(v):
                unknown(sub, f"{where}/{k}/{i}")
        elif k in SCHEMA_ONE:
            unknown(v, f"{where}/{k}")
