// The experiments the planner offers and their parameters with defaults, as
// planner/catalogue.py lists them (experiments.json; tests/web/test_server.py compares it
// with the catalogue, so the two cannot drift apart unnoticed). Values go to the server as
// the text typed: the server reads a string for a non-string parameter as the command line
// does, so its messages name exactly what is wrong.

import table from "./experiments.json";

export interface ParamSpec {
  name: string;
  type: "float" | "int" | "bool" | "floats" | "string" | "strings";
  optional?: boolean;
  default: string;
  /** The values a string parameter takes (the console offers them in a list). */
  choices?: string[];
}

export const EXPERIMENTS = table as Record<string, { title: string; params: ParamSpec[] }>;
