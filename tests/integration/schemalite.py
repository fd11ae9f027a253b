# SPDX-License-Identifier: GPL-3.0-or-later
"""The subset of JSON Schema (2020-12) that proto/schema uses, in python3
stdlib: type, const, enum, properties, required, additionalProperties,
items, minItems, maxProperties, minimum, maximum, exclusiveMinimum,
maxLength, pattern, oneOf, anyOf, $ref (to #/$defs/... in the same file
or FILE.json#/$defs/...). A keyword outside the subset is an error, so a
schema cannot silently use what is not checked."""
import json
import os
import re

KNOWN = {"$schema", "$id", "$defs", "$ref", "title", "description", "type", "const", "enum",
         "properties", "required", "additionalProperties", "items", "minItems", "maxProperties",
         "minimum", "maximum", "exclusiveMinimum", "maxLength", "pattern", "oneOf", "anyOf"}

TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


class SchemaSet:
    def __init__(self, directory):
        self.dir = directory
        self.files = {}
        for name in sorted(os.listdir(directory)):
            if name.endswith(".json"):
                with open(os.path.join(directory, name)) as f:
                    self.files[name] = json.load(f)
        for name, schema in self.files.items():
            self._check_keywords(schema, name)

    def _check_keywords(self, s, where):
        if isinstance(s, dict):
            for k, v in s.items():
                if k not in KNOWN:
                    raise ValueError(f"{where}: keyword {k} is outside the supported subset")
                if k in ("properties", "$defs"):
                    for name, sub in v.items():
                        self._check_keywords(sub, f"{where}/{k}/{name}")
                elif k in ("items", "additionalProperties") and isinstance(v, dict):
                    self._check_keywords(v, f"{where}/{k}")
                elif k in ("oneOf", "anyOf"):
                    for i, sub in enumerate(v):
                        self._check_keywords(sub, f"{where}/{k}/{i}")

    def resolve(self, ref, base):
        file, _, pointer = ref.partition("#")
        file = file or base
        node = self.files[file]
        for part in filter(None, pointer.split("/")):
            node = node[part]
        return node, file

    def errors(self, value, ref):
        """Every violation of value against ref ("FILE#/pointer")."""
        schema, base = self.resolve(ref, None)
        out = []
        self._validate(value, schema, base, "$", out)
        return out

    def _validate(self, v, s, base, path, out):
        if "$ref" in s:
            target, tbase = self.resolve(s["$ref"], base)
            self._validate(v, target, tbase, path, out)
        if "type" in s:
            types = s["type"] if isinstance(s["type"], list) else [s["type"]]
            if not any(TYPES[t](v) for t in types):
                out.append(f"{path}: {json.dumps(v)[:60]} is not {'/'.join(types)}")
                return
        if "const" in s and v != s["const"]:
            out.append(f"{path}: must be {s['const']!r}")
        if "enum" in s and v not in s["enum"]:
            out.append(f"{path}: {v!r} not in {s['enum']}")
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if "minimum" in s and v < s["minimum"]:
                out.append(f"{path}: {v} < {s['minimum']}")
            if "maximum" in s and v > s["maximum"]:
                out.append(f"{path}: {v} > {s['maximum']}")
            if "exclusiveMinimum" in s and v <= s["exclusiveMinimum"]:
                out.append(f"{path}: {v} <= {s['exclusiveMinimum']}")
        if isinstance(v, str):
            if "maxLength" in s and len(v) > s["maxLength"]:
                out.append(f"{path}: longer than {s['maxLength']}")
            if "pattern" in s and not re.search(s["pattern"], v):
                out.append(f"{path}: does not match {s['pattern']}")
        if isinstance(v, list):
            if "minItems" in s and len(v) < s["minItems"]:
                out.append(f"{path}: fewer than {s['minItems']} items")
            if "items" in s:
                for i, item in enumerate(v):
                    self._validate(item, s["items"], base, f"{path}[{i}]", out)
        if isinstance(v, dict):
            if "maxProperties" in s and len(v) > s["maxProperties"]:
                out.append(f"{path}: more than {s['maxProperties']} members")
            for r in s.get("required", []):
                if r not in v:
                    out.append(f"{path}: missing {r}")
            props = s.get("properties", {})
            extra = s.get("additionalProperties", True)
            for k, sub in v.items():
                if k in props:
                    self._validate(sub, props[k], base, f"{path}.{k}", out)
                elif extra is False:
                    out.append(f"{path}: unexpected member {k}")
                elif isinstance(extra, dict):
                    self._validate(sub, extra, base, f"{path}.{k}", out)
        for key in ("oneOf", "anyOf"):
            if key in s:
                matches = 0
                for sub in s[key]:
                    e = []
                    self._validate(v, sub, base, path, e)
                    matches += not e
                if (key == "oneOf" and matches != 1) or (key == "anyOf" and matches == 0):
                    out.append(f"{path}: matches {matches} of the {key} alternatives")
