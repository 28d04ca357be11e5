//! Expressions over a formula's inputs, parsed by `evalexpr` (a widely used expression crate)
//! once, checked once against what a formula may say, and evaluated by `evalexpr` with a
//! context that maps our function names onto `f64`'s methods.
//!
//! What an expression may say, checked on its tree ([`Expression::compile`]): numbers (every
//! number is a float: `1/2` is 0.5), the inputs, `+ - * / ^` (`-x^2` is `-(x^2)`; `^` groups
//! from the left like `/`: `2^3^2` is 64), parentheses and the functions of [`FUNCTIONS`]
//! (`min` and `max` of two arguments); a condition also `< <= > >= == !=`, `&& || !`.

use std::collections::BTreeMap;

use evalexpr::{Context, EvalexprError, EvalexprResult, Node, Operator, Value};

use super::error::FormulaError;

/// The functions an expression may call, by name.
pub const FUNCTIONS: [&str; 7] = ["exp", "ln", "sqrt", "tanh", "abs", "min", "max"];

/// Longest expression accepted (characters).
pub const MAX_LEN: usize = 2000;

/// What an expression is: a response's value, or a condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grammar {
    /// A number: arithmetic and functions.
    Response,
    /// True or false: comparisons of numbers, joined by `&& || !`.
    Condition,
}

/// The type of a sub-expression, as the check infers it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Type {
    Number,
    Truth,
    /// Two numbers: the arguments of `min` and `max`.
    Pair,
}

impl Type {
    fn name(self) -> &'static str {
        match self {
            Type::Number => "a number",
            Type::Truth => "a condition",
            Type::Pair => "a pair of numbers",
        }
    }
}

/// An expression, parsed and checked once, kept with its source text.
#[derive(Debug, Clone)]
pub struct Expression {
    source: String,
    tree: Node,
    grammar: Grammar,
}

impl PartialEq for Expression {
    fn eq(&self, other: &Self) -> bool {
        self.source == other.source && self.grammar == other.grammar
    }
}

/// Every integer literal made a float, so that arithmetic is never integer arithmetic.
fn floats_only(node: &mut Node) {
    if let Operator::Const {
        value: Value::Int(i),
    } = node.operator()
    {
        let value = Value::Float(*i as f64);
        *node.operator_mut() = Operator::Const { value };
    }
    for child in node.children_mut() {
        floats_only(child);
    }
}

/// The type of `node`, or why it is not a well-formed expression of `grammar` over `inputs`.
fn check(node: &Node, grammar: Grammar, inputs: &BTreeMap<String, f64>) -> Result<Type, String> {
    let children = node.children();
    // `arity` operands, each of type `want`.
    let each = |arity: usize, want: Type| -> Result<(), String> {
        if children.len() != arity {
            return Err(format!(
                "'{}' needs {arity} operand{}",
                node.operator().to_string().trim(),
                if arity == 1 { "" } else { "s" }
            ));
        }
        for child in children {
            let got = check(child, grammar, inputs)?;
            if got != want {
                return Err(format!(
                    "'{}' takes {}, not {}",
                    node.operator().to_string().trim(),
                    want.name(),
                    got.name()
                ));
            }
        }
        Ok(())
    };
    match node.operator() {
        Operator::RootNode => match children {
            [] => Err("an empty pair of parentheses".into()),
            [only] => check(only, grammar, inputs),
            _ => Err("two values side by side (an operator is missing)".into()),
        },
        Operator::Const {
            value: Value::Float(_) | Value::Int(_),
        } => Ok(Type::Number),
        Operator::VariableIdentifierRead { identifier } => {
            if inputs.contains_key(identifier) {
                Ok(Type::Number)
            } else {
                let known: Vec<&str> = inputs.keys().map(String::as_str).collect();
                Err(format!(
                    "unknown variable '{identifier}' (inputs: {})",
                    if known.is_empty() {
                        "none".to_owned()
                    } else {
                        known.join(", ")
                    }
                ))
            }
        }
        Operator::Add | Operator::Sub | Operator::Mul | Operator::Div | Operator::Exp => {
            each(2, Type::Number).map(|()| Type::Number)
        }
        Operator::Neg => each(1, Type::Number).map(|()| Type::Number),
        Operator::Tuple if children.len() == 2 => each(2, Type::Number).map(|()| Type::Pair),
        Operator::FunctionIdentifier { identifier } => {
            let want = match identifier.as_str() {
                "min" | "max" => Type::Pair,
                name if FUNCTIONS.contains(&name) => Type::Number,
                _ => {
                    return Err(format!(
                        "unknown function '{identifier}' (functions: {})",
                        FUNCTIONS.join(", ")
                    ))
                }
            };
            let [argument] = children else {
                return Err(format!("'{identifier}' takes one argument"));
            };
            let got = check(argument, grammar, inputs)?;
            if got != want {
                return Err(format!(
                    "'{identifier}' takes {}, not {}",
                    want.name(),
                    got.name()
                ));
            }
            Ok(Type::Number)
        }
        Operator::Eq
        | Operator::Neq
        | Operator::Gt
        | Operator::Lt
        | Operator::Geq
        | Operator::Leq
            if grammar == Grammar::Condition =>
        {
            each(2, Type::Number).map(|()| Type::Truth)
        }
        Operator::And | Operator::Or if grammar == Grammar::Condition => {
            each(2, Type::Truth).map(|()| Type::Truth)
        }
        Operator::Not if grammar == Grammar::Condition => {
            each(1, Type::Truth).map(|()| Type::Truth)
        }
        other => Err(format!(
            "'{}' is not allowed {} (operators: + - * / ^{}; functions: {})",
            other.to_string().trim(),
            match grammar {
                Grammar::Response => "in a response",
                Grammar::Condition => "in a condition",
            },
            match grammar {
                Grammar::Response => "",
                Grammar::Condition => " < <= > >= == != && || !",
            },
            FUNCTIONS.join(", ")
        )),
    }
}

impl Expression {
    /// Parses `source` and checks it is a well-formed expression of `grammar` whose every
    /// variable is a key of `inputs`. Errors name `field` (the expression's path in the spec).
    pub fn compile(
        source: &str,
        field: &str,
        grammar: Grammar,
        inputs: &BTreeMap<String, f64>,
    ) -> Result<Expression, FormulaError> {
        let invalid = |reason: String| FormulaError::Invalid {
            path: field.to_owned(),
            reason,
        };
        if source.trim().is_empty() {
            return Err(invalid("the expression is empty".into()));
        }
        if source.chars().count() > MAX_LEN {
            return Err(invalid(format!(
                "the expression is longer than {MAX_LEN} characters"
            )));
        }
        let mut tree = evalexpr::build_operator_tree(source)
            .map_err(|e| invalid(format!("cannot parse `{source}`: {e}")))?;
        floats_only(&mut tree);
        let got = check(&tree, grammar, inputs).map_err(invalid)?;
        let want = match grammar {
            Grammar::Response => Type::Number,
            Grammar::Condition => Type::Truth,
        };
        if got != want {
            return Err(invalid(format!(
                "`{source}` is {}; it must be {}",
                got.name(),
                want.name()
            )));
        }
        Ok(Expression {
            source: source.to_owned(),
            tree,
            grammar,
        })
    }

    /// The text it was parsed from.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Its value at `inputs` (which hold every variable: [`Expression::compile`] checked it):
    /// a number for a response, 1 (true) or 0 (false) for a condition.
    pub fn eval(&self, inputs: &BTreeMap<String, f64>) -> Result<f64, String> {
        let context = Inputs {
            values: inputs
                .iter()
                .map(|(name, value)| (name.as_str(), Value::Float(*value)))
                .collect(),
        };
        match self.tree.eval_with_context(&context) {
            Ok(Value::Float(x)) => Ok(x),
            Ok(Value::Boolean(b)) => Ok(if b { 1.0 } else { 0.0 }),
            Ok(other) => Err(format!("gave {other}, not a number")),
            Err(e) => Err(e.to_string()),
        }
    }
}

/// The evaluation context: the inputs' values and [`FUNCTIONS`], nothing else (the crate's
/// own built-in functions are off).
struct Inputs<'a> {
    values: BTreeMap<&'a str, Value>,
}

fn number(argument: &Value) -> EvalexprResult<f64> {
    argument.as_number()
}

fn pair(argument: &Value) -> EvalexprResult<(f64, f64)> {
    let pair = argument.as_fixed_len_tuple(2)?;
    Ok((number(&pair[0])?, number(&pair[1])?))
}

impl Context for Inputs<'_> {
    fn get_value(&self, identifier: &str) -> Option<&Value> {
        self.values.get(identifier)
    }

    fn call_function(&self, identifier: &str, argument: &Value) -> EvalexprResult<Value> {
        let value = match identifier {
            "exp" => number(argument)?.exp(),
            "ln" => number(argument)?.ln(),
            "sqrt" => number(argument)?.sqrt(),
            "tanh" => number(argument)?.tanh(),
            "abs" => number(argument)?.abs(),
            "min" => pair(argument).map(|(a, b)| a.min(b))?,
            "max" => pair(argument).map(|(a, b)| a.max(b))?,
            _ => return Err(EvalexprError::FunctionIdentifierNotFound(identifier.into())),
        };
        Ok(Value::Float(value))
    }

    fn are_builtin_functions_disabled(&self) -> bool {
        true
    }

    fn set_builtin_functions_disabled(&mut self, disabled: bool) -> EvalexprResult<()> {
        if disabled {
            Ok(())
        } else {
            Err(EvalexprError::BuiltinFunctionsCannotBeEnabled)
        }
    }
}
