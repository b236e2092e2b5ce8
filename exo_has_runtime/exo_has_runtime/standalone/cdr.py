"""Fast CDR (XCDR1, little endian) serialisers generated per message type.

The Cyclone DDS binding's own serialiser interprets a type description for every field of every
message (30-70 us for a HasState). Here each type gets Python source generated once: runs of
primitive fields are packed and unpacked by a single ``struct.Struct`` chosen for the run's
start alignment (there are only eight), strings and sequences are written inline. The bytes are
those of rmw_cyclonedds_cpp: the 4-byte encapsulation header ``00 01 00 00``, natural
alignment up to 8 counted from after the header, sequence elements aligned only when present,
and zero padding to a multiple of 4 at the end. Tests hold them equal to rosbags'
``serialize_cdr``.
"""

from __future__ import annotations

import array
import struct
import sys
from collections.abc import Callable, Mapping
from typing import Any

from rosbags.typesys.base import Nodetype  # type: ignore[attr-defined]

from exo_has_runtime.errors import MessageDefinitionError

#: The encapsulation header: CDR, little endian, no options.
HEADER = b'\x00\x01\x00\x00'

# ROS primitive: (struct code, size and alignment in bytes, array typecode or '').
_PRIMITIVES: dict[str, tuple[str, int, str]] = {
    'bool': ('?', 1, ''),
    'byte': ('B', 1, 'B'),
    'char': ('B', 1, 'B'),
    'uint8': ('B', 1, 'B'),
    'int8': ('b', 1, 'b'),
    'int16': ('h', 2, 'h'),
    'uint16': ('H', 2, 'H'),
    'int32': ('i', 4, 'i'),
    'uint32': ('I', 4, 'I'),
    'int64': ('q', 8, 'q'),
    'uint64': ('Q', 8, 'Q'),
    'float32': ('f', 4, 'f'),
    'float64': ('d', 8, 'd'),
}
if sys.byteorder != 'little':  # pragma: no cover - every ROS 2 tier-1 platform is little endian
    raise ImportError('exo_has_runtime.standalone.cdr assumes a little-endian host')

Serializer = Callable[[Any], bytes]
Deserializer = Callable[[bytes], Any]
FieldDefs = Mapping[str, tuple[list[Any], list[tuple[str, Any]]]]


def _run_structs(codes: list[tuple[str, int]]) -> list[struct.Struct]:
    """Return, per start offset modulo 8, the struct that packs a run with its padding."""
    layouts = []
    for start in range(8):
        fmt, offset = '<', start
        for code, size in codes:
            pad = -offset % size
            fmt += 'x' * pad + code
            offset += pad + size
        layouts.append(struct.Struct(fmt))
    return layouts


class _Generator:
    """Writes the source of the serialise/deserialise functions of one type and its children."""

    def __init__(self, fielddefs: FieldDefs, classes: Callable[[str], type[Any]]) -> None:
        self.fielddefs = fielddefs
        self.classes = classes
        self.namespace: dict[str, Any] = {
            'pack_u32': struct.Struct('<I').pack, 'unpack_u32': struct.Struct('<I').unpack_from,
            'array': array.array, 'bytes': bytes, 'len': len, 'list': list,
            'ValueError': ValueError,
        }
        self.done: set[str] = set()
        self.lines: list[str] = []
        self.counter = 0

    def name(self, prefix: str) -> str:
        self.counter += 1
        return f'{prefix}{self.counter}'

    @staticmethod
    def ident(type_name: str) -> str:
        return type_name.replace('/', '__')

    def generate(self, type_name: str) -> None:
        if type_name in self.done:
            return
        self.done.add(type_name)
        if type_name not in self.fielddefs:
            msg = f'no definition for {type_name}'
            raise MessageDefinitionError(msg)
        fields = self.fielddefs[type_name][1]
        for _, node in fields:
            nested = _nested_name(node)
            if nested is not None:
                self.generate(nested)
        self._write_function(type_name, fields)
        self._read_function(type_name, fields)

    def _runs(self, fields: list[tuple[str, Any]]) -> list[tuple[str, Any]]:
        """Group consecutive scalar primitives into ('run', [(name, code, size)]) items."""
        grouped: list[tuple[str, Any]] = []
        for field_name, node in fields:
            kind, arg = node
            if kind == Nodetype.BASE and arg[0] in _PRIMITIVES:
                code, size, _ = _PRIMITIVES[arg[0]]
                if grouped and grouped[-1][0] == 'run':
                    grouped[-1][1].append((field_name, code, size))
                else:
                    grouped.append(('run', [(field_name, code, size)]))
            else:
                grouped.append((field_name, node))
        return grouped

    def _write_function(self, type_name: str, fields: list[tuple[str, Any]]) -> None:
        lines = [f'def write_{self.ident(type_name)}(b, m):']
        for item_name, item in self._runs(fields):
            if item_name == 'run':
                structs = self.name('S')
                self.namespace[structs] = [s.pack for s in
                                           _run_structs([(c, s) for _, c, s in item])]
                values = ', '.join(f'm.{field}' for field, _, _ in item)
                lines.append(f'    b += {structs}[(len(b) - 4) & 7]({values})')
            else:
                lines.extend(self._write_value(f'm.{item_name}', item, '    ', item_name))
        lines.append('    return b')
        self.lines.extend([*lines, ''])

    def _write_value(self, expr: str, node: Any, indent: str, field: str) -> list[str]:
        kind, arg = node
        out: list[str] = []
        if kind == Nodetype.NAME:
            return [f'{indent}write_{self.ident(arg)}(b, {expr})']
        if kind == Nodetype.BASE:
            base, bound = arg
            if base != 'string':
                msg = f'field {field!r}: type {base!r} is not supported'
                raise MessageDefinitionError(msg)
            data = self.name('s')
            out += [f'{indent}{data} = {expr}.encode()']
            if bound:
                out += [f'{indent}if len({data}) > {bound}:',
                        f"{indent}    raise ValueError('field {field}: string longer than "
                        f"{bound}')"]
            out += [f'{indent}b += bytes(-len(b) & 3)',
                    f'{indent}b += pack_u32(len({data}) + 1)',
                    f'{indent}b += {data}',
                    f"{indent}b += b'\\0'"]
            return out
        (sub_kind, sub_arg), count = arg
        items = self.name('v')
        out.append(f'{indent}{items} = {expr}')
        if kind == Nodetype.SEQUENCE:
            if count:
                out += [f'{indent}if len({items}) > {count}:',
                        f"{indent}    raise ValueError('field {field}: more than {count} items')"]
            out += [f'{indent}b += bytes(-len(b) & 3)', f'{indent}b += pack_u32(len({items}))']
        else:
            out += [f'{indent}if len({items}) != {count}:',
                    f"{indent}    raise ValueError('field {field}: expected {count} items')"]
        if sub_kind == Nodetype.BASE and sub_arg[0] in _PRIMITIVES:
            code, size, typecode = _PRIMITIVES[sub_arg[0]]
            out.append(f'{indent}if len({items}):')
            if size > 1:
                out.append(f'{indent}    b += bytes(-(len(b) - 4) & {size - 1})')
            if typecode:
                out.append(f"{indent}    b += {items}.astype('<{code}').tobytes() if "
                           f"hasattr({items}, 'astype') else array('{typecode}', {items})"
                           '.tobytes()')
            else:
                out.append(f'{indent}    b += bytes(bool(x) for x in {items})')
            return out
        element = self.name('e')
        out.append(f'{indent}for {element} in {items}:')
        out.extend(self._write_value(element, (sub_kind, sub_arg), indent + '    ', field))
        return out

    def _read_function(self, type_name: str, fields: list[tuple[str, Any]]) -> None:
        cls = f'C_{self.ident(type_name)}'
        self.namespace[cls] = self.classes(type_name)
        lines = [f'def read_{self.ident(type_name)}(d, p):', f'    m = {cls}.__new__({cls})',
                 '    a = m.__dict__']
        for item_name, item in self._runs(fields):
            if item_name == 'run':
                structs = self.name('U')
                layouts = _run_structs([(c, s) for _, c, s in item])
                self.namespace[structs] = [(s.unpack_from, s.size) for s in layouts]
                names = ', '.join(f"a['{field}']" for field, _, _ in item)
                comma = ',' if len(item) == 1 else ''
                lines += [f'    u, n = {structs}[(p - 4) & 7]',
                          f'    {names}{comma} = u(d, p)',
                          '    p += n']
            else:
                lines.extend(self._read_value(f"a['{item_name}']", item, '    '))
        lines.append('    return m, p')
        self.lines.extend([*lines, ''])

    def _read_value(self, target: str, node: Any, indent: str) -> list[str]:
        kind, arg = node
        if kind == Nodetype.NAME:
            return [f'{indent}{target}, p = read_{self.ident(arg)}(d, p)']
        if kind == Nodetype.BASE:
            return [f'{indent}p += -(p - 4) & 3',
                    f'{indent}(n,) = unpack_u32(d, p)',
                    f'{indent}{target} = d[p + 4:p + 3 + n].decode(errors="replace")',
                    f'{indent}p += 4 + n']
        (sub_kind, sub_arg), count = arg
        out: list[str] = []
        length = self.name('n')
        if kind == Nodetype.SEQUENCE:
            out += [f'{indent}p += -(p - 4) & 3', f'{indent}({length},) = unpack_u32(d, p)',
                    f'{indent}p += 4']
        else:
            out.append(f'{indent}{length} = {count}')
        if sub_kind == Nodetype.BASE and sub_arg[0] in _PRIMITIVES:
            _code, size, typecode = _PRIMITIVES[sub_arg[0]]
            out.append(f'{indent}if {length} and {size} > 1:')
            out.append(f'{indent}    p += -(p - 4) & {size - 1}')
            if typecode:
                values = self.name('w')
                out += [f"{indent}{values} = array('{typecode}')",
                        f'{indent}{values}.frombytes(d[p:p + {length} * {size}])',
                        f'{indent}{target} = {values}.tolist()']
            else:
                out.append(f'{indent}{target} = [x != 0 for x in d[p:p + {length}]]')
            out.append(f'{indent}p += {length} * {size}')
            return out
        items = self.name('l')
        element = self.name('x')
        out += [f'{indent}{items} = []', f'{indent}for _ in range({length}):']
        out.extend(self._read_value(element, (sub_kind, sub_arg), indent + '    '))
        out += [f'{indent}    {items}.append({element})', f'{indent}{target} = {items}']
        return out


def _nested_name(node: Any) -> str | None:
    kind, arg = node
    if kind == Nodetype.NAME:
        return str(arg)
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return _nested_name(arg[0])
    return None


def generate_codec(type_name: str, fielddefs: FieldDefs,
                   classes: Callable[[str], type[Any]]) -> tuple[Serializer, Deserializer]:
    """Generate the serialiser and deserialiser of a message type.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Name``.
    fielddefs : FieldDefs
        The rosbags field definitions of the type and everything it nests.
    classes : Callable[[str], type]
        The message class of a type name; deserialised messages are its instances.

    Returns
    -------
    tuple[Serializer, Deserializer]
        ``serialize(message) -> bytes`` (header and padding included) and
        ``deserialize(data) -> message`` (data with its header; trailing padding ignored).

    """
    generator = _Generator(fielddefs, classes)
    generator.generate(type_name)
    source = '\n'.join(generator.lines)
    code = compile(source, f'<cdr codec of {type_name}>', 'exec')
    exec(code, generator.namespace)
    writer = generator.namespace[f'write_{_Generator.ident(type_name)}']
    reader = generator.namespace[f'read_{_Generator.ident(type_name)}']

    def serialize(message: Any) -> bytes:
        body = writer(bytearray(HEADER), message)
        body += bytes(-len(body) & 3)
        return bytes(body)

    def deserialize(data: bytes) -> Any:
        if data[1] != 1:
            msg = f'{type_name}: only little-endian CDR is supported (header {data[:4].hex()})'
            raise ValueError(msg)
        return reader(data, 4)[0]

    return serialize, deserialize
