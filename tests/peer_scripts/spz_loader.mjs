// Run by tests with node: decode an SPZ file with @spz-loader/core (Niantic's spz library built
// to wasm) and print the cloud as JSON.
// usage: node spz_loader.mjs NODE_MODULES FILE.spz [COORDINATE_SYSTEM]   (e.g. RDF: the PLY frame)
// On failure: the loader's message on stderr, exit code 3.
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
import { join } from "node:path";

const [modules, file, coord] = process.argv.slice(2);
// The package's bundle stubs out node:module, so its Node branch fails ("r is not a function");
// its wasm is embedded, so its browser branch runs under Node once it is told this is not Node.
process.type = "renderer";
const { loadSpz } = await import(pathToFileURL(join(modules, "@spz-loader/core/dist/index.js")).href);
// The loader activates what Niantic's library returns: scales exp(), alphas sigmoid(), colours
// DC * colorScaleFactor + 0.5; a factor of 1 keeps DC recoverable exactly (colour - 0.5).
const options = { colorScaleFactor: 1, ...(coord ? { unpackOptions: { coordinateSystem: coord } } : {}) };
try {
  const c = await loadSpz(readFileSync(file), options);
  const out = { numPoints: c.numPoints, shDegree: c.shDegree };
  for (const k of ["positions", "scales", "rotations", "alphas", "colors", "sh"]) out[k] = Array.from(c[k]);
  process.stdout.write(JSON.stringify(out));
} catch (e) {
  process.stderr.write(String((e && e.message) || e) + "\n");
  process.exit(3);
}
