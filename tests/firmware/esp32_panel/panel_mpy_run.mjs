// Run a Python script under the real MicroPython WebAssembly runtime (Node).
// usage: node panel_mpy_run.mjs <micropython.mjs> <script.py> [module files copied to / ...]
// Exit code 1 (and the traceback on stderr) when the script raises.
import { readFileSync } from "fs";
import { pathToFileURL } from "url";

const [modPath, script, ...files] = process.argv.slice(2);
const { loadMicroPython } = await import(pathToFileURL(modPath).href);
const mp = await loadMicroPython({
  stdout: (s) => process.stdout.write(s + "\n"),
  stderr: (s) => process.stderr.write(s + "\n"),
});
for (const f of files) {
  mp.FS.writeFile("/" + f.split("/").pop(), readFileSync(f));
}
try {
  mp.runPython("import sys\nsys.path.insert(0, '/')\n" + readFileSync(script, "utf8"));
} catch (e) {
  process.stderr.write(String(e) + "\n");
  process.exit(1);
}
