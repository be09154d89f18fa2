// Run a Python checker under the real MicroPython WebAssembly runtime (Node).
// usage: node wire_mpy_run.mjs <micropython.mjs> <checker.py> <file-to-copy>...
// Every extra file is written into the runtime's virtual FS at /<basename>; the checker runs with / on sys.path.
// Exit code: 0 if the checker finished without an exception, 1 otherwise (the Python error is printed on stderr).
import { readFileSync } from "node:fs";
import { basename } from "node:path";
import { pathToFileURL } from "node:url";

const [mpyPath, checkerPath, ...files] = process.argv.slice(2);
const { loadMicroPython } = await import(pathToFileURL(mpyPath).href);
const mp = await loadMicroPython({
  heapsize: 16 * 1024 * 1024,
  stdout: (line) => process.stdout.write(line + "\n"),
  stderr: (line) => process.stderr.write(line + "\n"),
});
for (const f of files) {
  mp.FS.writeFile("/" + basename(f), readFileSync(f));
}
let code = 0;
try {
  mp.runPython("import sys\nif '/' not in sys.path:\n    sys.path.insert(0, '/')\n");
  mp.runPython(readFileSync(checkerPath, "utf8"));
} catch (error) {
  process.stderr.write("MicroPython error: " + (error.message || String(error)) + "\n");
  code = 1;
}
process.exit(code);
