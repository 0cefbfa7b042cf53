#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""The house rules the compiler does not check (docs/architecture.md); ctest runs
this as Layout.Rules. Standard library only, any Python 3.

1. No include circle: among headers none; among modules (a header with its .cpp)
   none either, except a module's own detail/ header including the module's header
   back (an implementation header of it).
2. No file under apps/ over 600 lines (a driver stays a driver).
3. io holds formats and system I/O only: no simulation, noise or plotting source.
4. No function in a CUDA file (.cu, .cuh) over 80 lines: clang-tidy's
   readability-function-size (scripts/tidy.sh, .clang-tidy) checks the C++
   sources and their headers but cannot parse nvcc's files.
Prints every violation, one per line; exit 1 if any.
"""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAYERS = ("io", "gmf", "splat", "apps")
SOURCES = (".hpp", ".cpp", ".cu", ".cuh")
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def sources():
    for layer in LAYERS:
        for folder, _, names in os.walk(os.path.join(ROOT, layer)):
            for name in names:
                if name.endswith(SOURCES):
                    path = os.path.relpath(os.path.join(folder, name), ROOT)
                    yield path


def includes(path):
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        return [i for i in INCLUDE.findall(f.read()) if i.split("/")[0] in LAYERS]


def cycles(graph):
    """Strongly connected components of more than one node (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for start in list(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on.add(start)
        while work:
            node, edges = work[-1]
            advanced = False
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter[0]
                    counter[0] += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    advanced = True
                    break
                if nxt in on:
                    low[node] = min(low[node], index[nxt])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    top = stack.pop()
                    on.discard(top)
                    component.append(top)
                    if top == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


FUNCTION_LINES = 80
SCOPE = re.compile(r"^\s*(template\s*<[^{]*>\s*)?(namespace\b|extern\s+\"C\"|struct\b|class\b|union\b|enum\b)")


def long_functions(path):
    """(name line, lines) of each function body in `path` longer than FUNCTION_LINES:
    a brace opened outside any function, not by a namespace, struct, class, union or
    enum, starts one; its lines run to the matching brace (comments and strings skipped)."""
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        text = f.read()
    text = re.sub(r"//[^\n]*|/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)
    text = re.sub(r'"(\\.|[^"\\\n])*"', '""', text)
    out, stack, header = [], [], ""
    for number, line in enumerate(text.split("\n"), start=1):
        for ch in line:
            if ch == "{":
                in_function = any(kind == "function" for kind, _ in stack)
                kind = "scope" if in_function or SCOPE.match(header + line) else "function"
                if in_function:
                    kind = "block"
                stack.append((kind, number))
                header = ""
            elif ch == "}" and stack:
                kind, start = stack.pop()
                if kind == "function" and number - start - 1 > FUNCTION_LINES:
                    out.append((start, number - start - 1))
        stripped = line.strip()
        ends = not stripped or stripped.startswith("#") or stripped.endswith((";", "}", "{"))
        header = "" if ends else (header + " " + stripped)[-400:]
    return out


def main():
    problems = []
    files = sorted(sources())
    headers, modules = {}, {}
    for path in files:
        incs = includes(path)
        if path.endswith((".hpp", ".cuh")):
            headers[path] = {i for i in incs if i != path}
        module = os.path.splitext(path)[0]
        for inc in incs:
            target = os.path.splitext(inc)[0]
            own_detail = "/detail/" in inc and "/detail/" not in path and path.endswith((".cpp", ".cu"))
            back_to_owner = "/detail/" in path and not "/detail/" in inc
            if target != module and not own_detail and not back_to_owner:
                modules.setdefault(module, set()).add(target)
    for component in cycles(headers):
        problems.append("include circle among headers: " + " -> ".join(component))
    for component in cycles(modules):
        problems.append("include circle among modules: " + " <-> ".join(component))
    for path in files:
        if path.startswith("apps/"):
            with open(os.path.join(ROOT, path), encoding="utf-8") as f:
                lines = sum(1 for _ in f)
            if lines > 600:
                problems.append(f"{path}: {lines} lines, over the 600 a file under apps/ may have")
        if path.endswith((".cu", ".cuh")):
            for start, lines in long_functions(path):
                problems.append(f"{path}:{start}: a function of {lines} lines, over {FUNCTION_LINES}")
        if path.startswith("io/") and re.search(r"synthetic|noise|plot|simulat", os.path.basename(path)):
            problems.append(f"{path}: simulation or plotting in io/ (it holds formats and system I/O only)")
    for p in problems:
        print(p)
    if not problems:
        print(f"layout: {len(files)} sources: no include circle, apps files <= 600 lines, io formats only, "
              f"CUDA functions <= {FUNCTION_LINES} lines")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
