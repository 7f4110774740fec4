// What tests/units.test.mjs imports: the page's pure modules (no DOM).
export * from "../src/protocol";
export * from "../src/store";
export * from "../src/modelruns";
