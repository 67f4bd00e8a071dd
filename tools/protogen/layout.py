"""Questions the outputs ask of a loaded :class:`protogen.model.Protocol`: which messages are
dispatched, the parts (request, response) of a message, structs in dependency order and the
element count of a tail that fills the payload."""

from __future__ import annotations

from protogen.model import Field, Message, Protocol, StructDef


def dispatched(p: Protocol) -> list[Message]:
    return [m for m in p.messages if m.role in ("required", "weak") and m.name != "error"]


def tail_max(p: Protocol, fields: list[Field]) -> int:
    fixed = sum(f.t.size for f in fields)
    last = fields[-1]
    if last.t.kind == "tail":
        return p.max_payload - fixed
    return (p.max_payload - fixed) // p.structs[last.t.base].size


def struct_order(p: Protocol) -> list[StructDef]:
    order: list[StructDef] = []
    done: set[str] = set()

    def visit(name: str) -> None:
        if name in done:
            return
        for f in p.structs[name].fields:
            if f.t.kind in ("struct", "struct_array"):
                visit(f.t.base)
        done.add(name)
        order.append(p.structs[name])

    for name in sorted(p.structs):
        visit(name)
    return order


def msg_parts(m: Message) -> list[tuple[str, list[Field]]]:
    parts = [("req", m.request), ("resp", m.response)]
    if m.role == "stream" or m.name == "error":
        parts = [("resp", m.response)]
    elif m.posted:
        parts = [("req", m.request)]
    return parts
